"""test_cluster_nats_lost: a terrad node whose only NATS server dies while it
runs (docs/cluster.md, "Partitions and the loss of NATS servers"): the node
stops committing, /readyz answers 503 saying why, a client's pose batch is
refused with store_unavailable, the node keeps serving reads; when the server
is back (same store directory) the node takes its lapsed lease back, /readyz
is ready again and the world ticks on from where it was, in the same
process. Skipped (77) when nats-server is not installed.
"""
# ctest-timeout: 180
import asyncio
import os
import sys
import time
import urllib.error

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, wait_for  # noqa: E402
from service_harness import Checks, RecordingClient, skip, tp  # noqa: E402

check = Checks()


def readyz(node):
    try:
        status, body = node.get("/readyz")
    except urllib.error.HTTPError as e:
        status, body = e.code, e.read()
    return status, body.decode("utf-8", "replace")


def wait_ready(node, want, timeout):
    deadline = time.monotonic() + timeout
    status, body = readyz(node)
    while (status == 200) != want and time.monotonic() < deadline:
        time.sleep(0.1)
        status, body = readyz(node)
    return status, body


async def pose_refused(node):
    """A client's pose batch while nothing can be committed: the error it gets."""
    c = RecordingClient(node.ws, name="nats-lost", keep=1)
    await c.connect()
    try:
        cid = await c.create_collider("sphere", radius=0.4)
        await c.send_poses([tp.Pose(cid, 5.0, 5.0, 0.1, 1, 0, 0, 0)])
        await c.wait_for(lambda: c.errors, 10)
    except Exception:  # noqa: BLE001
        pass
    errors = list(c.errors)
    await c.close()
    return errors


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    node = None
    with ch.NatsCluster(1) as nats:
        try:
            urls = nats.urls
            ok, said = ch.world_add(urls, "dunes", "server/scene/default.json")
            check(ok, f"world add: {said}")
            node = Node("solo", urls)
            check(wait_for(lambda: node.serves("dunes"), 30), "the node serves dunes")
            check(readyz(node)[0] == 200, "ready while NATS is up")
            nats.servers[0].kill()
            status, body = wait_ready(node, False, 10)
            check(status == 503 and "NATS" in body,
                  f"/readyz says the node cannot commit ({status}: {body.strip()})")
            errors = asyncio.run(pose_refused(node))
            check(any("store_unavailable" in str(e) for e in errors),
                  f"a pose batch is refused with store_unavailable ({errors})")
            t0 = node.stats()["tick"]
            time.sleep(4)  # past the lease: the node stops claiming the world
            check(wait_for(lambda: node.stats()["tick"] > t0, 60),
                  "the node keeps ticking (serving reads) meanwhile")
            nats.servers[0].start()
            nats.servers[0].wait_listening()
            status, body = wait_ready(node, True, 30)
            check(status == 200, f"ready again once NATS is back ({status}: {body.strip()})")
            check(node.proc.poll() is None and
                  not any("no longer owns" in line for line in node.lines),
                  "the same process still owns dunes")
            t1 = node.stats()["tick"]
            check(wait_for(lambda: node.stats()["tick"] > t1, 60), "and ticks on")
        except Exception:  # noqa: BLE001
            import traceback
            check(False, "the test raised:\n" + traceback.format_exc())
        finally:
            if node:
                code = node.stop()
                check(code == 0, f"SIGTERM stops the node with status 0 ({code})")
                if check.failed:
                    node.print_log()
                    print(nats.logs())
    check.finish()


if __name__ == "__main__":
    main()
