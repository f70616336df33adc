# terrad: user-facing entry points. CMake does the real build work.
#
#   make deps           install missing Debian packages to build and run (scripts/deps --build)
#   make deps-test      ... and the test tools (scripts/deps --test: clang, chromium, node, ...)
#   make build          configure (once) and build everything into build/ (CC=clang -> build-clang/)
#   make run            build only the daemon, then run it: ./build/terrad serve $(ARGS)
#   make install        build the daemon, the client library and the twin library, then install them
#                       (PREFIX=/usr/local, DESTDIR= for staging; see packaging/)
#   make test           everything CI runs; ends with "N passed, N failed". It installs the
#                       WebAssembly toolchain, so a test that needs build/terrad_twin.wasm fails
#                       without it (TERRAD_REQUIRE_WASM=1) instead of skipping; likewise MuJoCo
#                       for the co-simulation example (TERRAD_REQUIRE_MUJOCO=1)
#   make test-stress    make test while a CPU hog runs beside it (stress-ng --cpu 2): the suite
#                       must pass at any load; the hog stops however make test ends, and the
#                       exit status is make test's
#   make bench          build, then run the benchmarks (build/bench_*, tests/bench/bench_*.py,
#                       terrad bench --trade: the speed/accuracy sweep into
#                       $(TRADE_OUT), default test-artifacts/trade/, and its plot)
#   make screenshot     a PNG of a running daemon's viewer (scripts/screenshot.mjs, headless
#                       Chromium): URL= (default make run's http://127.0.0.1:8080/), OUT=
#                       (default test-artifacts/screenshot.png); needs chromium and web-deps
#   make docs-images    refresh the pictures the docs show, on purpose: docs/viewer.png (the
#                       viewer test's picture of its trail), docs/trade/ (the sweep and its plot) and
#                       docs/validation-ding2011.png + the table in docs/validation.md (validation-plot)
#   make fuzz           each fuzz target for 5 minutes (make fuzz-smoke: 10 s each)
#   make soak           tests/soak/*.sh
#   make chaos          seeded random fault schedules (kill -9, SIGSTOP of nodes and NATS servers)
#                       against 3 NATS servers and 3 nodes; checks that no acknowledged tick is
#                       lost (tests/chaos/chaos.py): SEED= replays a run, SCHEDULES= (default
#                       200), FAULT_S= (default 10 s of faults per schedule)
#   make cluster        3 NATS servers + 3 terrad nodes on loopback, two demo worlds (Ctrl-C stops;
#                       installs nats-server with the test set when it is missing)
#   make format         clang-format -i the C sources (format-check: only check)
#   make web-deps       npm ci (when package-lock.json exists)
#   make clean          remove build trees and test artifacts

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := build
# Parallelism lives inside cmake/ctest; keep the top-level steps in order.
.NOTPARALLEL:
MAKEFLAGS += --no-print-directory

ARGS ?=
JOBS ?= 2
PYTHON := /usr/bin/python3
ARTIFACTS := test-artifacts
PREFIX ?= /usr/local
DESTDIR ?=
TRADE_OUT ?= $(ARTIFACTS)/trade
URL ?= http://127.0.0.1:8080/
OUT ?= $(ARTIFACTS)/screenshot.png

# One build tree per compiler: the default compiler uses build/, CC=clang uses build-clang/.
ifeq ($(filter cc gcc,$(notdir $(CC))),)
BUILD := build-$(notdir $(CC))
ASAN_BUILD := build-$(notdir $(CC))-asan
else
BUILD := build
ASAN_BUILD := build-asan
endif
FUZZ_BUILD := build-fuzz
FUZZ_CC ?= clang

TERRAD := ./$(BUILD)/terrad
TEST_ENV := TERRAD_SOURCE_DIR=$(CURDIR) TERRAD_BIN=$(CURDIR)/$(BUILD)/terrad

# Configure a build tree every time: a cache must not decide what the machine has. Configuring
# again costs a second or two and rebuilds nothing that did not change; it is what finds the
# WebAssembly toolchain (and so builds build/terrad_twin.wasm, which the daemon embeds) when it
# arrived after the tree was first configured, or drops it when it went away.
# $(call configure,DIR,CC,EXTRA CMAKE ARGS)
define configure
	@if [ ! -f $(1)/CMakeCache.txt ]; then \
	    echo "configure: $(1) (CC=$(2))"; \
	    CC=$(2) cmake -S . -B $(1) $(3); \
	else \
	    cmake -S . -B $(1) $(3) >/dev/null; \
	fi
endef

FORMAT_FILES = $(shell find server tests proto clients -type f \( -name '*.c' -o -name '*.h' \) 2>/dev/null)

.PHONY: deps deps-test build build-asan daemon run cluster install test test-stress bench docs-images fuzz \
        fuzz-smoke fuzz-build soak chaos format format-check web-deps screenshot clean

# Building and running need only --build (which includes --runtime); the test tools
# (about 1 GB: chromium, clang, prometheus, node) come with make test.
deps:
	@scripts/deps --build

deps-test:
	@scripts/deps --test

build: deps
	$(call configure,$(BUILD),$(CC),)
	cmake --build $(BUILD) -j $(JOBS)

build-asan: deps
	$(call configure,$(ASAN_BUILD),$(CC),-DCMAKE_BUILD_TYPE=Debug -DCMAKE_C_FLAGS_DEBUG="-O1 -g" -DTERRAD_SANITIZE=ON)
	cmake --build $(ASAN_BUILD) -j $(JOBS)

# The daemon alone: no unit tests, benchmarks or client library.
daemon: deps
	$(call configure,$(BUILD),$(CC),)
	cmake --build $(BUILD) -j $(JOBS) --target terrad

run: daemon
	exec $(TERRAD) serve $(ARGS)

cluster: daemon
	@command -v nats-server >/dev/null 2>&1 || scripts/deps --test
	exec $(PYTHON) scripts/cluster --bin $(TERRAD) $(ARGS)

# The install prefix is set at configure time too, so that the systemd unit, the man page
# and the example configuration name the paths they are installed under.
install: deps
	$(call configure,$(BUILD),$(CC),)
	cmake -S . -B $(BUILD) -DCMAKE_INSTALL_PREFIX=$(PREFIX) >/dev/null
	cmake --build $(BUILD) -j $(JOBS) --target terrad client twin
	DESTDIR=$(DESTDIR) cmake --install $(BUILD) --prefix $(PREFIX)

# make test: every step runs even when an earlier one fails, so CI sees all failures.
# The last line is "N passed, N failed": the sum over both ctest runs, plus one failure
# for each step that broke before tests could run (a build, web-deps, or the fuzz smoke).
test: deps-test
	@mkdir -p $(ARTIFACTS); rm -f $(ARTIFACTS)/ctest-*.log; broken=0; \
	if [ -f package-lock.json ]; then $(MAKE) --no-print-directory web-deps || broken=$$((broken+1)); fi; \
	if $(MAKE) --no-print-directory build; then \
	    TERRAD_REQUIRE_WASM=1 TERRAD_REQUIRE_MUJOCO=1 ctest --test-dir $(BUILD) --output-on-failure -j $(JOBS) 2>&1 \
	        | tee $(ARTIFACTS)/ctest-build.log || true; \
	else broken=$$((broken+1)); fi; \
	if $(MAKE) --no-print-directory build-asan; then \
	    ctest --test-dir $(ASAN_BUILD) --output-on-failure -L unit -j $(JOBS) 2>&1 | tee $(ARTIFACTS)/ctest-asan.log || true; \
	else broken=$$((broken+1)); fi; \
	$(MAKE) --no-print-directory fuzz-smoke || broken=$$((broken+1)); \
	cat $(ARTIFACTS)/ctest-*.log 2>/dev/null | awk -v broken=$$broken ' \
	    /tests passed, [0-9]+ tests? failed out of [0-9]+/ { failed += $$4; total += $$NF; runs++ } \
	    END { passed = total - failed; failed += broken; \
	          printf "%d passed, %d failed\n", passed, failed; exit (failed > 0) }' \
	    || { echo "make test: FAILED (logs in $(ARTIFACTS)/)" >&2; exit 1; }

# make test-stress: the whole make test with Debian's stress-ng holding two CPUs busy beside it,
# so a test that depends on the machine's speed fails here, not later on a busy CI machine
# (tests assert behaviour, never speed). The hog is killed on every way out (the EXIT trap;
# INT/TERM first turn into an exit); the status is make test's.
test-stress: deps-test
	@stress-ng --cpu 2 --quiet & hog=$$!; \
	trap 'kill $$hog 2>/dev/null || true; wait $$hog 2>/dev/null || true' EXIT; \
	trap 'exit 130' INT; trap 'exit 143' TERM; \
	echo "test-stress: stress-ng --cpu 2 (pid $$hog) runs beside make test"; \
	status=0; $(MAKE) --no-print-directory test || status=$$?; \
	echo "test-stress: make test exited $$status under load"; \
	exit $$status

bench: build
	@shopt -s nullglob; ran=0; \
	for b in $(BUILD)/bench_*; do \
	    [ -x "$$b" ] && [ -f "$$b" ] || continue; \
	    echo "== $$b"; $(TEST_ENV) "$$b"; ran=1; \
	done; \
	for b in tests/bench/bench_*.py; do \
	    echo "== $$b"; $(TEST_ENV) $(PYTHON) "$$b"; ran=1; \
	done; \
	if { $(TERRAD) --help 2>&1 || true; } | grep -qw bench; then \
	    echo "== $(TERRAD) bench --trade --out $(TRADE_OUT)"; \
	    $(TERRAD) bench --trade --out $(TRADE_OUT); \
	    $(PYTHON) scripts/trade-plot $(TRADE_OUT)/trade.csv $(TRADE_OUT)/trade.svg; ran=1; \
	else echo "bench: '$(TERRAD) bench' not available yet, skipped"; fi; \
	[ $$ran = 1 ] || echo "bench: no benchmarks found"

# Pictures in docs/ change only here, never as a side effect of make test or make bench.
docs-images: build web-deps
	@mkdir -p $(ARTIFACTS)
	ctest --test-dir $(BUILD) --output-on-failure -R '^test_viewer$$'
	cp $(ARTIFACTS)/viewer-trail.png docs/viewer.png
	$(TERRAD) bench --trade --out docs/trade
	$(PYTHON) scripts/trade-plot docs/trade/trade.csv docs/trade/trade.svg
	$(PYTHON) scripts/validation-plot --test $(BUILD)/test_single_wheel_ding2011

# A picture of the viewer of a daemon that is already running (make run in another terminal).
# Chromium and node come with scripts/deps --test; playwright-core with web-deps (once).
screenshot:
	@[ -x /usr/bin/chromium ] && command -v node >/dev/null || { \
	    echo "screenshot: needs chromium and node: scripts/deps --test" >&2; exit 1; }
	@[ -d node_modules/playwright-core ] || $(MAKE) --no-print-directory web-deps
	node scripts/screenshot.mjs --url '$(URL)' --out '$(OUT)'

# Fuzz targets: tests/fuzz/fuzz_*.c, built with clang + libFuzzer + ASan/UBSan in build-fuzz/.
# Seeds are read from tests/fuzz/corpus/<target>/ when it exists; new inputs and crashes go
# to test-artifacts/fuzz/.
FUZZ_TARGETS = $(patsubst tests/fuzz/%.c,%,$(wildcard tests/fuzz/fuzz_*.c))

fuzz-build: deps-test
	$(call configure,$(FUZZ_BUILD),$(FUZZ_CC),-DTERRAD_FUZZ=ON)
	cmake --build $(FUZZ_BUILD) -j $(JOBS) --target fuzz

# $(call fuzz_run,SECONDS)
define fuzz_run
	@if [ -z "$(FUZZ_TARGETS)" ]; then echo "fuzz: no tests/fuzz/fuzz_*.c targets, nothing to run"; exit 0; fi; \
	$(MAKE) --no-print-directory fuzz-build; \
	failed=0; \
	for t in $(FUZZ_TARGETS); do \
	    corpus=$(ARTIFACTS)/fuzz/$$t/corpus; mkdir -p $$corpus; \
	    seeds=; [ -d tests/fuzz/corpus/$$t ] && seeds=tests/fuzz/corpus/$$t; \
	    echo "== $$t for $(1) s"; \
	    if ./$(FUZZ_BUILD)/$$t -max_total_time=$(1) -print_final_stats=1 \
	        -artifact_prefix=$(ARTIFACTS)/fuzz/$$t/ $$corpus $$seeds \
	        > $(ARTIFACTS)/fuzz/$$t/log 2>&1; then \
	        tail -n 3 $(ARTIFACTS)/fuzz/$$t/log; \
	    else \
	        tail -n 40 $(ARTIFACTS)/fuzz/$$t/log; echo "fuzz: $$t FAILED"; failed=1; \
	    fi; \
	done; \
	exit $$failed
endef

fuzz-smoke:
	$(call fuzz_run,10)

fuzz:
	$(call fuzz_run,300)

chaos: build
	@command -v nats-server >/dev/null 2>&1 || scripts/deps --test
	$(TEST_ENV) $(PYTHON) tests/chaos/chaos.py $(if $(SEED),--seed $(SEED)) \
	    $(if $(SCHEDULES),--schedules $(SCHEDULES)) $(if $(FAULT_S),--fault-s $(FAULT_S))

soak: build
	@shopt -s nullglob; scripts=(tests/soak/*.sh); \
	if [ $${#scripts[@]} = 0 ]; then echo "soak: no tests/soak/*.sh"; exit 0; fi; \
	failed=(); for s in "$${scripts[@]}"; do echo "== $$s"; \
	    $(TEST_ENV) bash "$$s" || failed+=("$$s"); done; \
	if [ $${#failed[@]} != 0 ]; then echo "soak: FAILED: $${failed[*]}"; exit 1; fi; \
	echo "soak: all $${#scripts[@]} passed"

format:
	@[ -z "$(FORMAT_FILES)" ] || clang-format -i $(FORMAT_FILES)

format-check:
	@[ -z "$(FORMAT_FILES)" ] || clang-format --dry-run --Werror $(FORMAT_FILES)

web-deps:
	@if [ -f package-lock.json ]; then npm ci --no-audit --no-fund; \
	else echo "web-deps: no package-lock.json, nothing to install"; fi

clean:
	rm -rf build build-* $(ARTIFACTS)
