#!/usr/bin/python3
"""One limits table (issue 29 item 4): every limit is one row of NET_LIMITS
(server/net/net.h; net_limit_table in net_limits.c), from which the defaults, the
config's "limits" keys, the world message's "limits" and `terrad serve
--help`'s limits section are made. Checked here from the outside:

- --help lists every settable limit with its default, and each is a row of
  PROTOCOL.md's Limits table with the same default where that is a number;
  PROTOCOL.md lists no limit the daemon neither takes nor tells;
- a config that sets every limit --help lists (each to a value unlike its
  default) starts, the world message reports each value it tells, and HTTP
  holds to its own (max_heights_bytes_per_address);
- a limit whose 0 means none or its default (NET_LIMIT_ZERO: the tick and sweep
  budgets, the lag, the bandwidth budgets, the server's connection and HTTP caps)
  may be set to 0, and the world message tells the 0; any other limit may not;
- an unknown limit, a value that is not a positive number and a budget under
  hello's smallest (1024 bytes/s) are refused at start, naming the key.
"""
# ctest-timeout: 180
import asyncio
import json
import os
import re
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, json_file, skip  # noqa: E402

import terrad as tp  # noqa: E402

ROOT = os.environ.get("TERRAD_SOURCE_DIR",
                      os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", ".."))


def help_limits():
    """{name: default} from serve --help's limits section."""
    out = subprocess.run([BIN, "serve", "--help"], capture_output=True, text=True,
                         timeout=60).stdout
    rows, inside = {}, False
    for line in out.splitlines():
        if line.startswith("limits ("):
            inside = True
        elif inside and line.startswith("  "):
            name, default = line.split()[:2]
            rows[name] = float(default)
        elif inside:
            break
    return rows


def protocol_limits():
    """{name: first number of its default cell, or None} from PROTOCOL.md's Limits table."""
    with open(os.path.join(ROOT, "proto", "PROTOCOL.md")) as f:
        text = f.read()
    table = text[text.index("## Limits"):]
    table = table[:table.index("\n## ", 4)]
    rows = {}
    for m in re.finditer(r"^\| `(\w+)` \| ([^|]*) \|", table, re.M):
        num = re.match(r"\s*([0-9.]+)", m.group(2))
        rows[m.group(1)] = float(num.group(1)) if num else None
    return rows


async def told_limits(d):
    c = tp.TerradClient(d.ws)
    await c.connect()
    limits = c.world.get("limits", {})
    await c.close()
    return limits


def refused(check, limits, key, what, config=None):
    path = json_file(config if config is not None else {"limits": limits}, "terrad-limits")
    try:
        p = subprocess.run([BIN, "serve", "--config", path, "--no-data", "--http-port", "0",
                            "--ws-port", "0", "--backend", "cpu", "--no-demo", "--ticks", "1"],
                           capture_output=True, text=True, timeout=60)
    finally:
        os.unlink(path)
    named = key if config is not None else f"limits.{key}"
    check(p.returncode == 2 and named in p.stderr,
          f"{what} is refused at start, naming {named} ({p.returncode}): {p.stderr[-300:]}")


def main():
    if not os.access(BIN, os.X_OK):
        skip(f"no daemon binary at {BIN}")
    check = Checks()
    settable = help_limits()
    spec = protocol_limits()
    check(len(settable) >= 19, f"--help lists the settable limits: {sorted(settable)}")
    for name, default in settable.items():
        check(name in spec, f"{name} (--help) is a row of PROTOCOL.md's Limits table")
        if name in spec and spec[name] is not None and default != 0:
            check(spec[name] == default,
                  f"{name}: --help's default {default:g} is PROTOCOL.md's {spec[name]:g}")

    # every settable limit, set to a value unlike its default (and harmless)
    # (a budget is at least 1024 bytes/s, as hello's: 2048)
    wanted = {name: (default * 2 if default else 2048 if "budget" in name else 1000)
              for name, default in settable.items()}
    d = Daemon(config={"limits": wanted}, extra=("--no-data",), name="terrad-limits")
    with check.running(d):
        told = asyncio.run(told_limits(d))
        check(set(told) <= set(spec), f"the world message tells only PROTOCOL.md's limits: "
              f"{sorted(set(told) - set(spec))}")
        check(set(spec) <= set(told) | set(settable),
              f"PROTOCOL.md lists no limit the daemon neither takes nor tells: "
              f"{sorted(set(spec) - set(told) - set(settable))}")
        for name, value in wanted.items():
            if name in told:
                check(told[name] == value, f"world.limits.{name} is the config's {value:g}: "
                      f"{told[name]}")
        # an HTTP limit, which no client is told: 64x64 int32 heights pass 1000 bytes
        status, body, _ = d.get("/v1/heights?x=0&y=0&w=64&h=64")
        check(status == 429 and b"at most 1000 per address" in body,
              f"the config's max_heights_bytes_per_address reaches HTTP: {status} {body[:200]}")

    # 0 where it means none or the default (before NET_LIMIT_ZERO every one was refused)
    zeros = {"max_tick_cells": 0, "max_sweep_cells": 0, "max_client_lag_ticks": 0,
             "default_budget_bytes_per_s": 0, "max_budget_bytes_per_s": 0,
             "max_connections": 0, "max_heights_bytes_per_address": 0,
             "max_heights_bytes_in_flight": 0}
    d = Daemon(config={"limits": zeros}, extra=("--no-data",), name="terrad-limits-zero")
    with check.running(d):
        told = asyncio.run(told_limits(d))
        for name in zeros:
            if name in told and name != "max_client_lag_ticks":
                check(told[name] == 0, f"world.limits.{name} is the config's 0: {told[name]}")
        # its 0 means the default, 2 s of ticks, and the world message tells what is in force
        check(told.get("max_client_lag_ticks") == 120,
              f"max_client_lag_ticks 0 is 2 s of 60 Hz ticks: {told.get('max_client_lag_ticks')}")
        check(told.get("max_tick_cells") == 0 and told.get("max_sweep_cells") == 0,
              f"the tick and sweep budgets can be switched off by a config: {told}")
    refused(check, {"max_colliders": 0}, "max_colliders", "0 for a limit whose 0 means nothing")
    refused(check, {"max_tick_cells": -1}, "max_tick_cells", "a negative limit that may be 0")

    # the config's other numbers go through their options' rows: the same ranges and kinds
    # as the command line (before, "tick_hz": 59.5 and "wal_segment_bytes": 2e12 started)
    for key, value, what in (("tick_hz", 59.5, "a fractional tick_hz (--tick-hz takes whole hertz)"),
                             ("demo_actors", 2.5, "a fractional demo_actors"),
                             ("wal_segment_bytes", 2e12, "a wal_segment_bytes past --wal-segment-bytes' 2^40"),
                             ("http_port", 70000, "an http_port past 65535"),
                             ("max_worlds", 0, "max_worlds 0")):
        refused(check, None, f"{key}: must be", what, config={key: value})
    d = Daemon(config={"tick_hz": 30, "demo_actors": 0, "wal_segment_bytes": 65536},
               extra=("--no-data",), name="terrad-config-numbers")
    with check.running(d):
        status, body, _ = d.get("/v1/world")
        check(status == 200 and json.loads(body).get("tick_hz") == 30,
              f"the config's tick_hz 30 is in force: {status} {body[:200]}")

    refused(check, {"max_bogus_cells": 5}, "max_bogus_cells", "an unknown limit")
    refused(check, {"max_colliders": -3}, "max_colliders", "a negative limit")
    refused(check, {"max_tick_cells": "lots"}, "max_tick_cells", "a limit that is not a number")
    refused(check, {"max_budget_bytes_per_s": 1000}, "max_budget_bytes_per_s",
            "a budget under 1024 bytes/s")
    refused(check, {"default_budget_bytes_per_s": 1023.5}, "default_budget_bytes_per_s",
            "a default budget under 1024 bytes/s")
    check.finish()


if __name__ == "__main__":
    main()
