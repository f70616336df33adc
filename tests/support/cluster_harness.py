"""NATS servers for the cluster tests and scripts/cluster (docs/cluster.md):
start 1 or 3 real nats-server processes with JetStream on loopback, each
with its own store directory and server name (3: one cluster "terrad",
routes between all), wait until each accepts connections and JetStream
answers, and stop them (SIGTERM, or SIGKILL for a crash). Also Node, one
`terrad serve --cluster` process whose log says which worlds it ticks and on
which ports (pause: a SIGSTOP that waits until every thread has stopped),
world_add (`terrad world add`) and drive_and_kill (a client
drives in a world until its owner is killed); running_nodes (a test body over
nodes: stopped after, logs on failure) and the pieces of a one-world failover
against a twin (run_failover_test, owner_and_standby, drive_across_compaction,
take_over).

Not a test itself (ctest registers only test_*.py). Run with /usr/bin/python3.
"""
import contextlib
import glob
import json
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import tempfile
import threading
import time
import traceback
import urllib.error
import urllib.request

from waiting import wait_for  # noqa: F401  (the cluster tests import it from here too)

NATS_SERVER = shutil.which("nats-server")
# the one nats-server command line, shared with nats_test.h (the C tests)
NATS_START = os.path.join(os.path.dirname(os.path.abspath(__file__)), "nats-start")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def port_open(port):
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return True
    except OSError:
        return False


class NatsServer:
    """One nats-server; start() may be called again after stop()/kill() (same
    ports, same store directory: a restart)."""

    def __init__(self, name, store_dir, port=None, cluster_port=None):
        self.name = name
        self.store_dir = store_dir
        self.port = port or free_port()
        self.cluster_port = cluster_port or free_port()
        self.routes = []
        self.proc = None
        self.log_path = os.path.join(store_dir, "nats.log")

    @property
    def url(self):
        return f"nats://127.0.0.1:{self.port}"

    def start(self):
        os.makedirs(self.store_dir, exist_ok=True)
        args = [NATS_START, self.name, str(self.port), self.store_dir, self.log_path]
        if self.routes:
            args += [str(self.cluster_port), ",".join(self.routes)]
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)

    def wait_listening(self, timeout=10):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"{self.name} exited with {self.proc.returncode}:\n{self.log()}")
            if port_open(self.port):
                return
            time.sleep(0.05)
        raise RuntimeError(f"{self.name} does not listen on {self.port}:\n{self.log()}")

    def alive(self):
        return self.proc is not None and self.proc.poll() is None

    def stop(self, sig=signal.SIGTERM, timeout=10):
        if self.alive():
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode if self.proc else None

    def kill(self):
        return self.stop(signal.SIGKILL)

    def log(self, tail=30):
        try:
            with open(self.log_path, errors="replace") as f:
                return "".join(f.readlines()[-tail:])
        except OSError:
            return ""


class NatsCluster:
    """n (1 or 3) servers in root (default: a temporary directory, removed by
    stop()); base_port: client ports base_port.., cluster ports base_port+10..
    (default: free ports)."""

    def __init__(self, n=3, root=None, base_port=None):
        if NATS_SERVER is None:
            raise FileNotFoundError("nats-server")
        self.root = root or tempfile.mkdtemp(prefix="terrad-nats-")
        self.own_root = root is None
        self.base_port = base_port
        self.servers = [NatsServer(f"n{i}", os.path.join(self.root, f"n{i}"),
                                   base_port + i if base_port else None,
                                   base_port + 10 + i if base_port else None) for i in range(n)]
        self._route()

    def _route(self):
        if len(self.servers) > 1:
            for s in self.servers:
                s.routes = [f"nats://127.0.0.1:{o.cluster_port}" for o in self.servers if o is not s]

    @property
    def urls(self):
        return ",".join(s.url for s in self.servers)

    def start(self, timeout=20, attempts=5):
        """Starts every server. A port free_port() found may be taken by another
        test before nats-server binds it ("address already in use"): then the
        cluster starts again on new ports (only when they were not given)."""
        for attempt in range(attempts):
            for s in self.servers:
                s.start()
            try:
                for s in self.servers:
                    s.wait_listening(timeout)
                return self
            except RuntimeError as e:
                for s in self.servers:  # __exit__ does not run when __enter__ raises
                    s.kill()
                if self.base_port or "address already in use" not in str(e) or \
                        attempt == attempts - 1:
                    raise
                for s in self.servers:
                    shutil.rmtree(s.store_dir, ignore_errors=True)  # nothing was stored yet
                    s.port, s.cluster_port = free_port(), free_port()
                self._route()
        return self

    def stop(self):
        for s in self.servers:
            s.stop()
        if self.own_root:
            shutil.rmtree(self.root, ignore_errors=True)

    def logs(self):
        return "\n".join(f"---- {s.name} ----\n{s.log()}" for s in self.servers)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False


# ---- terrad nodes ---------------------------------------------------------------

LISTENS_RE = re.compile(r"node (\S+) listens on http://127\.0\.0\.1:(\d+)/ and websocket port (\d+)")
WORLD_SERVING_RE = re.compile(r"cluster: world (\S+): serving scene .*?, tick (\d+)\)")
LOST_RE = re.compile(r"no longer owns world (\S+) |cluster: world (\S+) stopped here")


def threads_stopped(pid):
    """True when each thread of process pid is stopped (state T in
    /proc/PID/task/*/stat; a thread that has exited meanwhile counts)."""
    states = []
    for path in glob.glob(f"/proc/{pid}/task/*/stat"):
        try:
            with open(path) as f:
                stat = f.read()
        except OSError:
            continue  # gone since the listing
        states.append(stat[stat.rindex(")") + 2])
    return bool(states) and all(state in "TZX" for state in states)


def binary():
    from service_harness import BIN  # the one place that knows where terrad is
    return BIN


def world_add(urls, name, scene):
    """`terrad world add NAME --scene SCENE` (a path from the source root, or
    absolute): (ok, what it said on stderr)."""
    from service_harness import SOURCE
    r = subprocess.run([binary(), "world", "add", name, "--scene", os.path.join(SOURCE, scene),
                        "--cluster", urls], capture_output=True, text=True, timeout=60)
    return r.returncode == 0, r.stderr.strip()


class Node:
    """One `terrad serve --cluster` process that may tick several worlds
    (--max-worlds, default 1): its ports come from the "listens on" line of
    its log, and the worlds it serves now from the "world X: serving scene"
    and "no longer owns world X" lines (read by a thread; a node that loses a
    world goes on in the same process). start() again after kill9(): a
    restart."""

    def __init__(self, name, urls, max_worlds=1, extra=()):
        self.name = name
        self.urls = urls
        self.max_worlds = max_worlds
        self.extra = list(extra)
        self.lines = []
        self.start()

    def start(self):
        self.http = self.ws = None
        self.worlds = set()
        self.recovered = {}  # world -> the tick it was recovered at (its "serving" line)
        self.standby = False
        self.listening = threading.Event()
        self.proc = subprocess.Popen(
            [binary(), "serve", "--cluster", self.urls, "--node", self.name, "--http-port", "0",
             "--ws-port", "0", "--backend", "cpu", "--no-demo", "--max-worlds",
             str(self.max_worlds)] + self.extra,
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            text=True, errors="replace")
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stderr:
            self.lines.append(line)
            m = LISTENS_RE.search(line)
            if m:
                self.http = f"http://127.0.0.1:{m.group(2)}"
                self.ws = f"ws://127.0.0.1:{m.group(3)}/"
                self.listening.set()
            m = WORLD_SERVING_RE.search(line)
            if m:
                self.worlds.add(m.group(1))
                self.recovered[m.group(1)] = int(m.group(2))
            if "is a standby" in line:
                self.standby = True
            m = LOST_RE.search(line)
            if m:
                self.worlds.discard(m.group(1) or m.group(2))

    @property
    def world(self):
        """The world it serves (the first by name when several), or None."""
        return min(self.worlds) if self.worlds and self.proc.poll() is None else None

    def serves(self, world):
        return self.proc.poll() is None and world in self.worlds

    def up(self):
        """Running, listening, and past its first look at the leases: it ticks
        a world or waits as a standby (ready to take one over)."""
        return self.proc.poll() is None and self.listening.is_set() and bool(
            self.worlds or self.standby)

    def get(self, path):
        """(status, body) also for 4xx/5xx answers."""
        try:
            with urllib.request.urlopen(self.http + path, timeout=10) as r:
                return r.status, r.read()
        except urllib.error.HTTPError as e:
            return e.code, e.read()

    def stats(self, world=None):
        """GET /v1/stats (of world): the JSON, or None when not 200."""
        status, body = self.get("/v1/stats" + (f"?world={world}" if world else ""))
        return json.loads(body) if status == 200 else None

    def heights(self, world, x, y, w, h, layer=None):
        """(tick, heights) of GET /v1/heights?world=... (layer="compaction": the memory)"""
        extra = f"&layer={layer}" if layer else ""
        with urllib.request.urlopen(f"{self.http}/v1/heights?world={world}&x={x}&y={y}&w={w}"
                                    f"&h={h}{extra}", timeout=10) as r:
            tick = r.headers.get("X-Terrad-Tick")
            body = r.read()
        return (int(tick) if tick else None), list(struct.unpack(f"<{w * h}i", body))

    def kill9(self):
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()

    def pause(self, timeout=30):
        """SIGSTOP, then true once every thread of the node has stopped. kill()
        returns when the signal is queued: the kernel wakes one thread to take
        it, and only when that thread runs does it stop the others, so on a
        busy machine the node goes on meanwhile (its NATS and HTTP threads
        answer). Measured beside stress-ng --cpu 2 (Intel Xeon, 2 cores, load
        7.7): terrad answered HTTP after 57 of 200 SIGSTOPs. A test of a node
        that does not answer asks it only once this is true."""
        self.proc.send_signal(signal.SIGSTOP)
        return wait_for(lambda: threads_stopped(self.proc.pid), timeout, step=0.01)

    def resume(self):
        self.proc.send_signal(signal.SIGCONT)

    def stop(self):
        if self.proc.poll() is None:
            self.listening.wait(15)  # a node that has just started: past its start-up first
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def print_log(self, tail=40):
        print(f"---- node {self.name}, last {tail} lines ----\n" + "".join(self.lines[-tail:]))
        logdir = os.environ.get("TERRAD_CLUSTER_LOGDIR")
        if logdir:  # the whole log, for a soak's post-mortem
            os.makedirs(logdir, exist_ok=True)
            with open(os.path.join(logdir, f"node-{self.name}.log"), "w") as f:
                f.write("".join(self.lines))


def owner_of(nodes, world, timeout=30, step=0.05):
    """The node of nodes that serves world (waiting up to timeout s), or None."""
    return wait_for(lambda: next((n for n in nodes if n.serves(world)), None), timeout, step)


def node_reader(node, world):
    """read(x, y, w, h, layer=None) of world through node (its owner or a relay), asked again
    on a 503 (a sim thread too busy to serve the read in time on a loaded machine) for up to a
    minute."""
    def read(x, y, w, h, layer=None):
        end = time.monotonic() + 60
        while True:
            try:
                return node.heights(world, x, y, w, h, layer=layer)
            except urllib.error.HTTPError as e:
                if e.code != 503 or time.monotonic() > end:
                    raise
                time.sleep(0.2)
    return read


def all_zero(codes):
    """running_nodes' usual stopped: every node's exit status is 0."""
    return all(c == 0 for c in codes)


@contextlib.contextmanager
def running_nodes(check, nodes, nats=None, tail=40, stopped=None,
                  said="SIGTERM stops every node with status 0"):
    """The cluster form of Checks.running: runs a test body over nodes (a list the body may
    still fill); an exception is a failed check; then every node is stopped (SIGTERM) and, given
    stopped, stopped(codes) must hold (said names it); after any failure each node's log (its
    last tail lines) and, given nats, the NATS servers' logs are printed."""
    try:
        yield nodes
    except Exception:  # noqa: BLE001
        check(False, "the test raised:\n" + traceback.format_exc())
    finally:
        codes = [n.stop() for n in nodes]
        if stopped is not None:
            check(stopped(codes), f"{said} ({codes})")
        if check.failed:
            for n in nodes:
                n.print_log(tail)
            if nats is not None:
                print(nats.logs())


def owner_and_standby(check, nodes, world, what="the world"):
    """The node that takes world (what names it in the check) and, once every node is up, the
    other one of two: (owner, standby), or (None, None) when no node took it."""
    owner = owner_of(nodes, world, 60)
    if not check(owner is not None, f"a node takes {what}"):
        return None, None
    wait_for(lambda: all(n.up() for n in nodes), 60)
    return owner, next(n for n in nodes if n is not owner)


def compactions(node, world):
    """How many compactions of world's log into tile snapshots node has logged so far."""
    said = re.compile(rf"cluster: world {re.escape(world)}: \d+ tiles compacted")
    return sum(1 for line in list(node.lines) if said.search(line))


def drive_across_compaction(check, owner, world, first, second):
    """first(), then a wait until owner has compacted world's log into tile snapshots, then
    second(): a takeover after it reads both kinds of record (snapshots, log records after)."""
    first()
    before = compactions(owner, world)
    check(wait_for(lambda: compactions(owner, world) > before, 120),
          "the owner compacts the log into tile snapshots after the first half")
    second()


def take_over(check, owner, standby, world):
    """owner killed with SIGKILL; the standby must take world, recovering from tile snapshots and
    log records after them (its log says how many). The new owner, or None."""
    owner.kill9()
    new = owner_of([standby], world, 120)
    if not check(new is not None, f"{standby.name} takes the world after the kill"):
        return None
    said = re.compile(rf"cluster: world {re.escape(world)} recovered at tick \d+ from (\d+) tile "
                      r"snapshots and (\d+) log records")
    found = [m for m in map(said.search, list(new.lines)) if m]
    tiles, records = (int(found[-1].group(1)), int(found[-1].group(2))) if found else (0, 0)
    check(tiles > 0 and records > 0,
          f"the new owner recovered from tile snapshots ({tiles}) and log records after them "
          f"({records})")
    return new


async def settled(c, sid, park, quiet=30, timeout=120):
    """Lift the sphere out of the terrain (park: its pose high above) and wait,
    by condition, until the terrain is quiescent: the lift acknowledged, then the
    mirror unchanged over `quiet` acknowledged ticks in a row. A fixed sleep
    here once let a loaded machine kill the owner before the lift's ACK came,
    so the comparison was with a tick older than the owner's last commit (a
    moving target, not a lost tick). Raises TimeoutError after timeout s."""
    import asyncio
    seq = await c.send_poses([park])
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    last, since = None, None
    while loop.time() < deadline:
        await asyncio.sleep(1 / 60)
        await c.send_poses([park])  # a batch each tick keeps the ACKs (and the tick) current
        if c.acked_seq < seq:
            continue
        heights = c.mirrors[sid].heights
        if last != heights:
            last, since = list(heights), c.acked_tick
        elif c.acked_tick - since >= quiet:
            return
    raise TimeoutError(f"the terrain did not settle within {timeout} s (acked tick {c.acked_tick})")


async def drive_and_kill(owner, run_s, settle, world=None, half_lane=16, radius=0.3, speed=3.0,
                         dip=0.18, end=None):
    """A client on owner (a Node; world: the hello's, else the node's first)
    subscribes to a lane 2 * half_lane rows high across the world's middle and
    drives a sphere along it, dip m into the terrain, for run_s seconds; then
    owner is killed (SIGKILL) — at once, or (settle) after lifting the sphere
    out of the terrain and waiting until nothing changes any more (settled).
    end: called instead of the SIGKILL (a test's own way to stop the owner:
    SIGTERM). Returns
    (the last acknowledged tick, the lane, the heights of the client's mirror
    at that ACK, or None)."""
    import asyncio
    from service_harness import RecordingClient, tp
    asyncio.get_running_loop().set_exception_handler(lambda loop, context: None)
    c = RecordingClient(owner.ws, name="driver", keep=1, world=world)
    await c.connect()
    w = c.world
    lane = (0, w["height"] // 2 - half_lane, w["width"], 2 * half_lane)
    sid = await c.subscribe(*lane)
    await c.wait_for(lambda: c.mirrors[sid].complete, 30)
    cid = await c.create_collider("sphere", radius=radius)
    cs, upm = w["cell_size_m"], w["units_per_m"]
    mirror = c.mirrors[sid]
    x, y, vx = 1.0, (lane[1] + half_lane) * cs, speed
    t_end = time.monotonic() + run_s
    while time.monotonic() < t_end:
        x += vx / 60
        if x < 0.5 or x > w["width"] * cs - 0.5:
            vx = -vx
        cx, cy = int(x / cs), int(y / cs) - mirror.y
        ground = mirror.heights[cy * mirror.w + cx] / upm
        await c.send_poses([tp.Pose(cid, x, y, ground + dip, 1, 0, 0, 0)])
        await asyncio.sleep(1 / 60)
    if settle:
        await settled(c, sid, tp.Pose(cid, x, y, 50.0, 1, 0, 0, 0))
    (end or owner.kill9)()
    await asyncio.sleep(0.3)
    copy = c.history.get(c.acked_tick)
    try:
        await c.close()
    except Exception:  # noqa: BLE001
        pass
    return c.acked_tick, lane, (copy[sid][0] if copy else None)


def run_failover_test(check, world, scene, twin, failover, compare):
    """The frame of a one-world failover test against a twin (test_cluster_soil_failover,
    test_cluster_compaction_failover): twin(d) runs the reference on d, a single daemon of the
    scene that is never failed (every tick durable); one NATS server, the world registered from
    the scene file, two nodes; failover(nodes) drives, kills the owner and returns what the new
    owner served (falsy when it already failed a check); compare(check, ref, got, what) holds it
    against the twin. Logs are printed when a check failed; the scene file is removed. Ends the
    test (check.finish)."""
    from service_harness import Daemon, skip
    if NATS_SERVER is None:
        os.unlink(scene)
        skip("nats-server is not installed")
    try:
        d = Daemon(extra=["--scene", scene], name="terrad-twin", durability="every-tick")
        check.daemons.append(d)
        try:
            ref = twin(d)
        finally:
            d.stop()
        with NatsCluster(1) as nats, running_nodes(check, [], nats) as nodes:
            ok, said = world_add(nats.urls, world, scene)
            check(ok, f"world add {world}: {said}")
            nodes += [Node(f"n{i}", nats.urls) for i in range(2)]
            got = failover(nodes)
            if got:
                compare(check, ref, got, "kill -9 of the owner and a takeover")
    finally:
        os.unlink(scene)
    check.finish()
