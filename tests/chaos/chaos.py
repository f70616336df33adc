"""chaos: seeded, randomised fault schedules against a terrad cluster, and a
checker that no acknowledged tick is ever lost (docs/cluster.md, "Chaos").
Jepsen's approach on a small scale: real processes on loopback — 3
nats-servers (JetStream, 3 replicas) and 3 `terrad serve --cluster` nodes
(--max-worlds 2) ticking 3 worlds — with one client per world driving a
sphere through its world on the world's owner and recording every ACK and
its mirror, while a schedule of faults runs:

  node-kill    kill -9 of a node, started again 0.5-4 s later
  nats-kill    kill -9 of a NATS server, started again (same store) 0.5-4 s later
  leader-kill  the same, of the server leading the stream TERRAD_WAL (asked
               of the JetStream API when the fault fires)
  node-pause   SIGSTOP of a node for 1-5 s, then SIGCONT (a pause that looks
               like a partition: its lease runs out, another node takes over)
  nats-pause   SIGSTOP of a NATS server for 1-5 s, then SIGCONT

1-3 faults per schedule, at random times within FAULT_S seconds, so they
overlap ("several at once"). The one bound: a NATS server is killed only
while every other is up and caught up (the promise is the loss of one server
at a time, and a server back from kill -9 counts as lost until it has caught
up: nats-server does not fsync each write — docs/cluster.md); pauses overlap
anything. Then everything is healed (continued,
restarted), every world must tick and commit again, the clients lift their
spheres and wait until the terrain is quiescent, and the owner of a random
world is killed: a settled kill, after which the new owner's heights must
equal the client's mirror of its last acknowledged tick.

The checker, for every world:
  lost       at every takeover (a node's "world X: serving scene ... tick R"
             line, at time T), every ACK the clients received before T has a
             tick <= R: an acknowledged tick is in the log the new owner
             recovered from (an ACK received before T was sent before the new
             owner served the world, by an owner of an earlier epoch, whose
             commits are all in the log the new owner read, or fenced off).
  mirror     after a settled kill, GET /v1/heights of the lane on the new
             owner equals the client's mirror at its last ACK, and the
             recovered tick is >= that ACK.
  Σh         the world's volume (Σ heights) never changes: deformation moves
             material, never makes or loses it.
  fencing    the world's log, read from the stream's leader, is one history:
             record ticks strictly increase along it, across every owner
             marker; two owners committing would interleave their ticks.

Every schedule's faults come from random.Random(f"{seed}:{i}"); the cluster
carries over from one schedule to the next, so a failing schedule i is
replayed by running the same seed up to it: the output says how
(`make chaos SEED=S SCHEDULES=i+1`). Ends with one summary line:
"chaos: seed S: N schedules, F faults, A acknowledged ticks checked, L lost".

A run that checked nothing fails too, naming its seed: a schedule in which no
acknowledged tick was compared with a recovery, owners killed but no takeover
seen, a client session dead of an exception that is a bug rather than a lost
connection, fewer settled checks than --min-settled, no ACK for every world
within 60 s of the start; --budget-s cuts every wait to what is left of it.

  /usr/bin/python3 tests/chaos/chaos.py [--seed S] [--schedules N] [--fault-s F]
                                        [--logdir DIR] [--budget-s B] [--min-settled M]
Exit status: 0 all checks held, 1 a check failed, 77 nats-server missing.
"""
import argparse
import asyncio
import bisect
import calendar
import os
import random
import re
import shutil
import signal
import sys
import threading
import time
import traceback

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
sys.path.insert(0, HERE)
import cluster_harness as ch  # noqa: E402
import nats_api  # noqa: E402
from cluster_harness import Node, wait_for  # noqa: E402
from service_harness import RecordingClient, tp  # noqa: E402

SCENE = "tests/chaos/chaos_scene.json"
WORLDS = ["c0", "c1", "c2"]
NODES = 3
MAX_WORLDS = 2
HALF_LANE = 8
KINDS = ["node-kill", "node-kill", "nats-kill", "leader-kill", "node-pause", "nats-pause"]
SERVING_RE = re.compile(r"^(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d)\.(\d{3})Z terrad info: cluster: world "
                        r"(\S+): serving scene .*?, tick (\d+)\)")


def log(msg):
    print(f"{time.strftime('%H:%M:%S')} {msg}", flush=True)


def stamp_seconds(date, ms):
    return calendar.timegm(time.strptime(date, "%Y-%m-%dT%H:%M:%S")) + int(ms) / 1000.0


# ---- the schedule ------------------------------------------------------------------------

def make_schedule(seed, i, fault_s):
    """The faults of schedule i: (at_s, kind, target index, how long)."""
    rng = random.Random(f"{seed}:{i}")
    faults = []
    for _ in range(rng.choice([1, 2, 2, 3])):
        kind = rng.choice(KINDS)
        at = rng.uniform(0.0, fault_s - 1.0)
        target = rng.randrange(NODES if kind.startswith("node") else 3)
        length = rng.uniform(1.0, 5.0) if kind.endswith("pause") else rng.uniform(0.5, 4.0)
        faults.append((round(at, 2), kind, target, round(length, 2)))
    faults.sort()
    return faults, rng.randrange(1 << 30)


class Proc:
    """A process the faults act on: a NATS server or a node."""

    def __init__(self, name, obj, is_node):
        self.name, self.obj, self.is_node = name, obj, is_node
        self.paused = False
        self.down = False
        self.catching_up = False

    @property
    def pid(self):
        return self.obj.proc.pid

    def alive(self):
        return self.obj.proc is not None and self.obj.proc.poll() is None

    def kill(self):
        if self.paused:
            self.paused = False
        if self.is_node:
            self.obj.kill9()
        else:
            self.obj.kill()
        self.down = True

    def pause(self):
        os.kill(self.pid, signal.SIGSTOP)
        self.paused = True

    def resume(self):
        if self.paused and self.alive():
            os.kill(self.pid, signal.SIGCONT)
        self.paused = False

    def restart(self):
        if not self.alive():
            self.obj.start()
            if not self.is_node:
                self.obj.wait_listening(30)
                self.catching_up = True  # until every stream's replicas are current
        self.down = False


# ---- the clients ---------------------------------------------------------------------------

class Driver:
    """One client per world, for the whole run: connects to the world's
    owner (as the nodes' logs say), subscribes to a lane across the world's
    middle, drives a sphere along it, and records every ACK with the time it
    was received; when its connection ends (the owner killed, paused, or the
    world moved) it connects again to whichever node serves the world then.
    park(): lift the sphere and wait until the terrain is quiescent."""

    def __init__(self, world, run):
        self.world = world
        self.run = run
        self.times = []   # receive times (time.time()) of every ACK, in order
        self.ticks = []   # their ticks
        self.prefix_max = []
        self.parked = False
        self.settled = None  # (acked tick, lane heights at it) once quiescent after park()
        self.client = None
        self.node = None
        self.connects = 0
        self.checked_upto = 0  # the ACKs before this index were compared with a recovery
        self.errors = []  # tracebacks of sessions that ended by an exception other than a lost
        #                   connection: a bug of the driver or the client, which must fail the run

    def on_ack(self, tick, _seq):
        self.times.append(time.time())
        self.ticks.append(tick)
        self.prefix_max.append(max(tick, self.prefix_max[-1]) if self.prefix_max else tick)

    def max_acked_before(self, t):
        """The largest tick of an ACK received before time t, or None."""
        k = bisect.bisect_left(self.times, t)
        return self.prefix_max[k - 1] if k > 0 else None

    def acks_before(self, t):
        return bisect.bisect_left(self.times, t)

    async def _session(self, node):
        c = RecordingClient(node.ws, name=f"chaos-{self.world}", keep=4, world=self.world,
                            open_timeout=5, ping_interval=None)
        c.on_ack = self.on_ack
        self.client, self.node = c, node
        await asyncio.wait_for(c.connect(), 10)
        w = c.world
        lane = (0, w["height"] // 2 - HALF_LANE, w["width"], 2 * HALF_LANE)
        self.lane = lane
        sid = await asyncio.wait_for(c.subscribe(*lane), 10)
        await c.wait_for(lambda: c.mirrors[sid].complete, 20)
        cid = await asyncio.wait_for(c.create_collider("sphere", radius=0.3), 10)
        self.connects += 1
        cs, upm = w["cell_size_m"], w["units_per_m"]
        mirror = c.mirrors[sid]
        rng = random.Random(self.connects)
        x, y, vx = rng.uniform(1.0, w["width"] * cs - 1.0), (lane[1] + HALF_LANE) * cs, 3.0
        park_seq, last, since = None, None, None
        while not self.run.stopping:
            if c._reader is not None and c._reader.done():
                return  # the connection ended
            if self.parked:
                seq = await c.send_poses([tp.Pose(cid, x, y, 50.0, 1, 0, 0, 0)])
                if park_seq is None:
                    park_seq, last, since = seq, None, None
                if c.acked_seq >= park_seq and self.settled is None:
                    heights = list(mirror.heights)
                    if last != heights:
                        last, since = heights, c.acked_tick
                    elif c.acked_tick - since >= 30:
                        self.settled = (c.acked_tick, c.history.get(c.acked_tick, {}).get(sid))
            else:
                park_seq = None
                x += vx / 60
                if x < 0.5 or x > w["width"] * cs - 0.5:
                    vx = -vx
                cx, cy = int(x / cs), int(y / cs) - mirror.y
                ground = mirror.heights[cy * mirror.w + cx] / upm
                await c.send_poses([tp.Pose(cid, x, y, ground + 0.15, 1, 0, 0, 0)])
            await asyncio.sleep(1 / 60)

    async def main(self):
        asyncio.get_running_loop().set_exception_handler(lambda loop, context: None)
        while not self.run.stopping:
            node = self.run.owner(self.world)
            if node is None or node.ws is None:
                await asyncio.sleep(0.1)
                continue
            try:
                await self._session(node)
            except (AttributeError, TypeError, NameError, IndexError, KeyError,
                    ZeroDivisionError, AssertionError):
                # a bug of the driver or the client: it would end every session of this
                # world at once and leave it unchecked, so it fails the run
                self.errors.append(traceback.format_exc())
            except Exception:  # noqa: BLE001 — the owner died, paused or gave the world
                pass  # away (closed connections, timeouts, a ServerError at hello): again
            c, self.client = self.client, None
            if c is not None:
                try:
                    await asyncio.wait_for(c.close(), 2)
                except Exception:  # noqa: BLE001
                    pass
            await asyncio.sleep(0.1)


# ---- the run -------------------------------------------------------------------------------

class Run:
    def __init__(self, args):
        self.args = args
        self.stopping = False
        self.failures = []
        self.faults = 0
        self.kinds = {}
        self.takeovers = 0
        self.takes_redone = 0  # takes confirmed only the second time (cluster_wal_take)
        self.lost = set()
        self.records = 0
        self.log_seq = {w: 1 for w in WORLDS}
        self.log_tick = {w: 0 for w in WORLDS}
        self.seen_lines = {}   # node name -> lines of its log already read
        self.settled_checks = 0
        self.settled_skipped = 0
        self.schedule = -1
        self.done = 0
        self.saved = None
        # every wait of the run ends by this time (--budget-s), so a slow run fails with a
        # message before an outer timeout (ctest's) kills it silently
        self.deadline = time.monotonic() + args.budget_s if args.budget_s else None

    def left(self, timeout):
        """timeout, cut to what is left of the run's budget (at least 1 s)."""
        if self.deadline is None:
            return timeout
        return max(1.0, min(timeout, self.deadline - time.monotonic()))

    # -- state of the nodes, from their logs --
    def owner(self, world):
        """The node serving world now, not paused, as the logs say; None when none."""
        for p in self.node_procs:
            n = p.obj
            if not p.paused and n.serves(world):
                return n
        return None

    def fail(self, what):
        msg = f"FAIL (schedule {self.schedule}): {what}"
        self.failures.append(msg)
        log(msg)
        if self.args.logdir and self.saved != self.schedule:  # the logs as they are now
            self.saved = self.schedule
            self.save_logs(os.path.join(self.args.logdir, f"schedule-{self.schedule}"))

    def committing(self, world, since):
        n = self.owner(world)
        try:
            st = n.stats(world) if n else None
        except Exception:  # noqa: BLE001
            st = None
        return st is not None and st["tick"] > since and st.get("ready", True)

    def volume(self, world):
        n = self.owner(world)
        try:
            st = n.stats(world) if n else None
        except Exception:  # noqa: BLE001
            return None
        return st["volume"] if st else None

    # -- the checks --
    def check_takeovers(self):
        """Every new "serving" line: ACKs received before it are <= its tick."""
        for p in self.node_procs:
            lines = p.obj.lines
            start = self.seen_lines.get(p.name, 0)
            self.seen_lines[p.name] = len(lines)
            for line in lines[start:]:
                if "not clean:" in line:  # a take that found another writer's record, redone
                    self.takes_redone += 1
                    log(f"node {p.name}: {line.split('cluster: ', 1)[-1].strip()}")
                m = SERVING_RE.match(line)
                if not m:
                    continue
                t = stamp_seconds(m.group(1), m.group(2))
                world, rec = m.group(3), int(m.group(4))
                d = self.drivers[world]
                self.takeovers += 1
                n = d.acks_before(t)
                d.checked_upto = max(d.checked_upto, n)
                best = d.max_acked_before(t)
                if best is not None and best > rec:
                    lost = {tk for tk in d.ticks[:n] if tk > rec}
                    self.lost |= {(world, tk) for tk in lost}
                    self.fail(f"{world}: node {p.name} recovered it at tick {rec}, but the client "
                              f"had ACKs of ticks up to {best} before ({len(lost)} acknowledged "
                              f"ticks lost)")

    def check_log(self):
        """Fencing: each world's log, from where the last check ended, is one history."""
        for w in WORLDS:
            try:
                entries = nats_api.read_log(self.nats.urls, w, self.log_seq[w])
            except (OSError, nats_api.NatsError) as e:
                self.fail(f"{w}: the log cannot be read from the stream's leader: {e}")
                continue
            back = []
            for seq, kind, what in entries:
                self.log_seq[w] = seq + 1
                if kind != "record":
                    continue
                self.records += 1
                if what <= self.log_tick[w]:
                    back.append((seq, what, self.log_tick[w]))
                self.log_tick[w] = max(self.log_tick[w], what)
            if back:
                seq, tick, after = back[0]
                self.fail(f"{w}: log sequence {seq} holds tick {tick} after tick {after} "
                          f"({len(back)} records out of order): two writers committed, or a "
                          f"writer started again from a log it read short")

    def check_volumes(self, when):
        for w in WORLDS:
            v = wait_for(lambda: self.volume(w), self.left(20))
            if v != self.volumes[w]:
                self.fail(f"{w}: Σh {v} {when}, not {self.volumes[w]}")

    # -- phases --
    def wait_all_committing(self, timeout=180):
        timeout = self.left(timeout)
        t0 = time.monotonic()
        if not wait_for(lambda: all(p.obj.up() for p in self.node_procs), timeout, 0.1):
            return False
        if not wait_for(lambda: nats_api.streams_current(self.nats.urls), timeout, 0.2):
            return False  # every NATS server back and caught up before the next schedule
        for q in self.nats_procs:
            q.catching_up = False
        for w in WORLDS:
            left = max(1.0, timeout - (time.monotonic() - t0))

            def ticking(w=w):
                n = self.owner(w)
                try:
                    st = n.stats(w) if n else None
                except Exception:  # noqa: BLE001
                    st = None
                return st["tick"] if st and st.get("ready", True) else None

            base = wait_for(ticking, left, 0.1)
            if base is None or not wait_for(lambda: self.committing(w, base + 30), left, 0.1):
                return False
        return True

    def run_faults(self, faults):
        t0 = time.monotonic()
        events = []  # (at, order, action, fault)
        for f in faults:
            at, kind, target, length = f
            events.append((at, 0, "start", f))
            events.append((at + length, 1, "end", f))
        events.sort(key=lambda e: (e[0], e[1]))
        acting = {}  # fault -> Proc it acts on
        for at, _, action, f in events:
            delay = at - (time.monotonic() - t0)
            if delay > 0:
                time.sleep(delay)
            _, kind, target, _ = f
            if action == "start" and kind in ("nats-kill", "leader-kill"):
                # the promise covers the loss of one NATS server at a time: no kill while
                # another server is down or back but not yet caught up (nats-server does
                # not fsync each write — docs/cluster.md); a paused one keeps what it has,
                # so pauses do not count
                if any(q.catching_up for q in self.nats_procs) and \
                        nats_api.streams_current(self.nats.urls):
                    for q in self.nats_procs:
                        q.catching_up = False
                busy = [q.name for q in self.nats_procs if q.down or q.catching_up]
                if busy:
                    log(f"  {kind}: NATS server {', '.join(busy)} down or catching up; skipped")
                    continue
            if action == "start":
                if kind == "leader-kill":
                    leader = nats_api.stream_leader(self.nats.urls)
                    p = next((q for q in self.nats_procs if q.name == leader), None)
                    if p is None:
                        log(f"  {kind}: no stream leader found now; skipped")
                        continue
                else:
                    procs = self.node_procs if kind.startswith("node") else self.nats_procs
                    p = procs[target]
                if p.down or p.paused or not p.alive():
                    log(f"  {kind} {p.name}: already down or paused; skipped")
                    continue
                acting[f] = p
                if kind.endswith("pause"):
                    p.pause()
                else:
                    p.kill()
                self.faults += 1
                self.kinds[kind] = self.kinds.get(kind, 0) + 1
                log(f"  t={time.monotonic() - t0:5.1f} s {kind} {'nats ' if not p.is_node else 'node '}"
                    f"{p.name}")
            else:
                p = acting.pop(f, None)
                if p is None:
                    continue
                if kind.endswith("pause"):
                    p.resume()
                else:
                    p.restart()
                log(f"  t={time.monotonic() - t0:5.1f} s {kind} {p.name} ends")
        for p in self.nats_procs + self.node_procs:  # heal whatever is left
            p.resume()
            p.restart()

    def settled_kill(self, rng):
        """Park every driver, wait until quiescent, kill the owner of a random
        world: its new owner's heights equal the mirror at the last ACK."""
        for d in self.drivers.values():
            d.settled = None
            d.parked = True
        ok = wait_for(lambda: all(d.settled for d in self.drivers.values()), self.left(60), 0.1)
        world = rng.choice(WORLDS)
        d = self.drivers[world]
        owner = self.owner(world)
        if not ok or owner is None or d.node is not owner or d.settled[1] is None:
            # a skip is logged and counted; --min-settled makes too few settled checks fail
            self.settled_skipped += 1
            log(f"  settled kill skipped: {world} not quiescent on its owner")
            for dd in self.drivers.values():
                dd.parked = False
            return
        acked, (heights, complete) = d.settled
        proc = next(p for p in self.node_procs if p.obj is owner)
        moved = sorted(owner.worlds)
        proc.kill()
        self.faults += 1
        self.kinds["settled-kill"] = self.kinds.get("settled-kill", 0) + 1
        others = [p.obj for p in self.node_procs if p.obj is not owner]
        new = ch.owner_of(others, world, self.left(60), step=0.05)
        if new is None:
            self.fail(f"{world}: no node took it over within 60 s of the settled kill")
        else:
            rec = new.recovered.get(world, -1)
            lane = d.lane
            try:
                _, now = new.heights(world, *lane)
            except Exception as e:  # noqa: BLE001
                now = f"GET /v1/heights failed: {e}"
            self.settled_checks += 1
            if rec < acked:
                self.fail(f"{world}: settled kill of {owner.name}: recovered at tick {rec} < "
                          f"the last acknowledged tick {acked}")
            if not complete or now != heights:
                self.fail(f"{world}: settled kill of {owner.name}: the heights of its lane on "
                          f"{new.name} differ from the client's mirror at tick {acked}")
        log(f"  settled kill of node {owner.name} (worlds {moved}; {world} acked {acked}): "
            f"{new.name if new else 'nobody'} recovered it at tick "
            f"{new.recovered.get(world, -1) if new else '-'}")
        proc.restart()
        for dd in self.drivers.values():
            dd.parked = False

    def one_schedule(self, i):
        self.schedule = i
        faults, sub_seed = make_schedule(self.args.seed, i, self.args.fault_s)
        log(f"schedule {i} (seed {self.args.seed}:{i}): "
            + "; ".join(f"{k} {'#' + str(t) if k != 'leader-kill' else ''} at {a} s for {ln} s"
                        for a, k, t, ln in faults))
        self.run_faults(faults)
        if not self.wait_all_committing():
            self.fail("after the faults healed, not every world ticks and commits within 180 s "
                      "(liveness)")
            return False
        self.check_volumes("after the faults")
        self.settled_kill(random.Random(sub_seed))
        if not self.wait_all_committing():
            self.fail("after the settled kill, not every world ticks and commits within 180 s")
            return False
        before = sum(d.checked_upto for d in self.drivers.values())
        self.check_takeovers()
        if sum(d.checked_upto for d in self.drivers.values()) == before:
            self.fail("no acknowledged tick was checked against a recovery in this schedule "
                      "(no takeover, and the settled kill skipped)")
        self.check_log()
        self.check_volumes("at the end of the schedule")
        return True

    def main(self):
        a = self.args
        with ch.NatsCluster(3) as nats:
            self.nats = nats
            self.nats_procs = [Proc(s.name, s, False) for s in nats.servers]
            self.node_procs = []
            loop_thread = None
            try:
                for w in WORLDS:
                    ok, said = ch.world_add(nats.urls, w, SCENE)
                    if not ok:
                        raise RuntimeError(f"world add {w}: {said}")
                self.node_procs = [Proc(f"t{k}", Node(f"t{k}", nats.urls, max_worlds=MAX_WORLDS),
                                        True) for k in range(NODES)]
                if not self.wait_all_committing():
                    raise RuntimeError("the worlds do not all tick and commit at the start")
                self.volumes = {w: self.volume(w) for w in WORLDS}
                self.drivers = {w: Driver(w, self) for w in WORLDS}
                loop = asyncio.new_event_loop()

                async def clients():
                    await asyncio.gather(*(d.main() for d in self.drivers.values()))

                loop_thread = threading.Thread(target=lambda: loop.run_until_complete(clients()),
                                               daemon=True)
                loop_thread.start()
                if not wait_for(lambda: all(d.ticks for d in self.drivers.values()),
                                self.left(60)):
                    self.fail("not every world's client received an ACK within 60 s of the "
                              "start: " + ", ".join(f"{w} {len(d.ticks)} ACKs"
                                                    for w, d in self.drivers.items()))
                for i in range(a.schedules if not self.failures else 0):
                    if not self.one_schedule(i) or (self.failures and not a.keep_going):
                        break
                    self.done += 1
                # the end: the clients stop, every node is killed at once, and every
                # world recovered: each ACK of the run is checked against a recovery
                self.stopping = True
                loop_thread.join(15)
                if not self.failures or a.keep_going:
                    self.schedule = "end"
                    for p in self.node_procs:
                        p.kill()
                        self.faults += 1
                        self.kinds["final-kill"] = self.kinds.get("final-kill", 0) + 1
                    for p in self.node_procs:
                        p.restart()
                    if not self.wait_all_committing():
                        self.fail("after every node was killed and started again, not every "
                                  "world ticks and commits within 180 s")
                    self.check_takeovers()
                    self.check_log()
                    self.check_volumes("at the end")
            except Exception:  # noqa: BLE001
                self.fail("the run raised:\n" + traceback.format_exc())
            finally:
                self.stopping = True
                if loop_thread:
                    loop_thread.join(10)
                for p in self.nats_procs + self.node_procs:
                    p.resume()
                if self.failures or a.logdir:
                    self.save_logs(os.path.join(a.logdir, "end") if a.logdir else None)
                for p in self.node_procs:
                    p.obj.stop()
        drivers = list(getattr(self, "drivers", {}).values())
        acked = sum(len(set(d.ticks)) for d in drivers)
        checked = sum(len(set(d.ticks[:d.checked_upto])) for d in drivers)
        kinds = ", ".join(f"{v} {k}" for k, v in sorted(self.kinds.items()))
        # a run that checked nothing must not pass: the checks above only compare what
        # happened, so say when too little happened for them to mean anything (the
        # processes are gone: these failures are recorded without saving logs)
        def fail(what):
            self.failures.append(f"FAIL ({self.schedule}): {what}")
            log(self.failures[-1])

        for d in drivers:
            for tb in d.errors[:1]:
                fail(f"{d.world}: the client's session died of an exception "
                          f"({len(d.errors)} times), not of a lost connection:\n{tb}")
        if drivers and checked == 0:
            fail("no acknowledged tick was checked against a recovery")
        if self.takeovers == 0 and any(k in self.kinds for k in
                                       ("node-kill", "settled-kill", "final-kill")):
            fail("owners were killed but no takeover (\"serving\" line) was seen")
        if self.settled_checks < a.min_settled:
            fail(f"{self.settled_checks} settled checks, fewer than --min-settled "
                      f"{a.min_settled} ({self.settled_skipped} settled kills skipped: a world "
                      f"not quiescent on its owner within 60 s)")
        if self.deadline is not None and time.monotonic() > self.deadline:
            fail(f"the run took longer than its budget of {a.budget_s:g} s (--budget-s): "
                      f"its waits were cut short")
        print(f"chaos: seed {a.seed}: {self.done} schedules of {a.schedules}, fault window "
              f"{a.fault_s:g} s; {self.faults} faults ({kinds}); "
              f"{checked} acknowledged ticks checked (of {acked} acknowledged) in "
              f"{self.takeovers} takeovers ({self.takes_redone} takes redone) and "
              f"{self.settled_checks} settled kills; "
              f"{self.records} log records checked for fencing; {len(self.lost)} lost; "
              f"{len(self.failures)} failed checks", flush=True)
        if self.failures:
            for f in self.failures:
                print(f"chaos: seed {a.seed}: {f.splitlines()[0]}", flush=True)
            print(f"chaos: FAILED — replay: make chaos SEED={a.seed} SCHEDULES="
                  f"{self.schedule + 1 if isinstance(self.schedule, int) else a.schedules}"
                  f"{' FAULT_S=' + str(a.fault_s) if a.fault_s != 10.0 else ''}", flush=True)
            return 1
        print("chaos: every acknowledged tick survived", flush=True)
        return 0

    def save_logs(self, d=None):
        """Every node's whole log and every NATS server's log into d (default
        --logdir), or their tails printed when there is none."""
        d = d or self.args.logdir
        if not d:
            for p in self.node_procs:
                p.obj.print_log(40)
            print(self.nats.logs())
            return
        os.makedirs(d, exist_ok=True)
        for p in self.node_procs:
            with open(os.path.join(d, f"node-{p.name}.log"), "w") as f:
                f.write("".join(p.obj.lines))
        for s in self.nats.servers:
            try:
                shutil.copyfile(s.log_path, os.path.join(d, f"nats-{s.name}.log"))
            except OSError:
                pass


def parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=int(os.environ.get("SEED") or 0) or
                    random.SystemRandom().randrange(1, 1 << 30))
    ap.add_argument("--schedules", type=int, default=int(os.environ.get("SCHEDULES") or 200))
    ap.add_argument("--fault-s", type=float, default=float(os.environ.get("FAULT_S") or 10.0))
    ap.add_argument("--logdir", default=os.environ.get("CHAOS_LOGDIR"))
    ap.add_argument("--budget-s", type=float, default=None,
                    help="every wait ends by this many seconds after the start (default none)")
    ap.add_argument("--min-settled", type=int, default=0,
                    help="fail when fewer settled kills were checked (default 0)")
    ap.add_argument("--keep-going", action="store_true",
                    help="go on after a failed check (the default stops at the first)")
    return ap.parse_args(argv)


def main(argv=None):
    if ch.NATS_SERVER is None:
        print("skip: nats-server is not installed", flush=True)
        return 77
    # SIGTERM, and SIGINT also where a shell started the run in the background (which
    # ignores it), end the run through its clean-up: the nodes and servers it started stop
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    return Run(parse(argv)).main()


if __name__ == "__main__":
    sys.exit(main())
