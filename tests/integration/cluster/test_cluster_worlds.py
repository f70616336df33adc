"""test_cluster_worlds: `terrad world add | list | remove` against real
nats-server processes (tests/support/cluster_harness.py): one server, then a
3-server JetStream cluster that keeps the registry with one server killed.
Bad input from the cluster side: a taken name, an unknown world, a scene the
daemon's parser refuses, a bad name, and NATS unreachable (the error names
the URL). Skipped (77) when nats-server is not installed.
"""
# ctest-timeout: 180
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))

import cluster_harness as ch  # noqa: E402
from service_harness import BIN, SOURCE, Checks, skip  # noqa: E402

SCENE = os.path.join(SOURCE, "server", "scene", "default.json")


def world(urls, *args):
    p = subprocess.run([BIN, "world", *args, "--cluster", urls], capture_output=True, text=True,
                       timeout=60)
    return p.returncode, p.stdout, p.stderr


def registry_round_trip(check, urls, label):
    rc, out, err = world(urls, "list")
    check(rc == 0 and out == "", f"{label}: list of an empty registry ({rc}, {out!r}, {err!r})")
    for name in ("dunes", "canyon"):
        rc, out, err = world(urls, "add", name, "--scene", SCENE)
        check(rc == 0 and f"world {name} added" in out, f"{label}: add {name} ({rc}, {err!r})")
    rc, out, err = world(urls, "add", "dunes", "--scene", SCENE)
    check(rc == 1 and "already exists" in err, f"{label}: a taken name is refused ({rc}, {err!r})")
    rc, out, err = world(urls, "list")
    check(rc == 0 and out.split("\n")[:2] == ["canyon -", "dunes -"],
          f"{label}: list names both worlds, sorted, no owner yet ({out!r})")


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    check = Checks()

    # NATS unreachable: the error names the URL
    url = f"nats://127.0.0.1:{ch.free_port()}"
    rc, out, err = world(url, "list")
    check(rc == 1 and url in err, f"unreachable NATS: exit 1 naming {url} ({rc}, {err!r})")

    with ch.NatsCluster(1) as one:
        urls = one.urls
        registry_round_trip(check, urls, "1 server")
        with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
            f.write('{"world": {"width": -1}}')
            bad = f.name
        rc, out, err = world(urls, "add", "bad", "--scene", bad)
        os.unlink(bad)
        check(rc == 1 and "scene refused" in err and "world.width" in err,
              f"a scene the parser refuses is not registered ({rc}, {err!r})")
        rc, out, err = world(urls, "add", "bad name", "--scene", SCENE)
        check(rc == 2 and "only letters" in err, f"a bad world name ({rc}, {err!r})")
        rc, out, err = world(urls, "add", "nofile")
        check(rc == 2 and "--scene" in err, f"add without --scene ({rc}, {err!r})")
        rc, out, err = world(urls, "remove", "dunes")
        check(rc == 0 and "world dunes removed" in out, f"remove ({rc}, {err!r})")
        rc, out, err = world(urls, "remove", "dunes")
        check(rc == 1 and 'no world named "dunes"' in err, f"remove an unknown world ({rc}, {err!r})")
        rc, out, err = world(urls, "list")
        check(rc == 0 and out == "canyon -\n", f"list after remove ({out!r})")
        rc, out, err = world(urls, "frobnicate")
        check(rc == 2 and "expected add, list or remove" in err, f"an unknown verb ({rc}, {err!r})")

    with ch.NatsCluster(3) as three:
        urls = three.urls
        registry_round_trip(check, urls, "3 servers")
        three.servers[0].kill()
        for _ in range(3):  # as an operator would: again while the cluster elects new leaders
            rc, out, err = world(",".join(s.url for s in three.servers[1:]), "list")
            if rc == 0:
                break
        check(rc == 0 and out.split("\n")[:2] == ["canyon -", "dunes -"],
              f"3 servers, one killed: the registry is still there ({rc}, {out!r}, {err!r})")
        if check.failed:
            print(three.logs())
    check.finish()


if __name__ == "__main__":
    main()
