"""nats_api: the few JetStream API requests the chaos checker makes
(tests/chaos/chaos.py), over the NATS text protocol on a plain socket — which
server leads the stream TERRAD_WAL, and a world's log read message by message
from the stream's leader — so the checker needs no NATS client library. Each
check opens a fresh connection to the first server that answers: the one it
used last may have been killed or paused since.

Protocol: https://docs.nats.io/reference/reference-protocols/nats-protocol
(INFO, CONNECT, PING/PONG, SUB, PUB, MSG, HMSG); JetStream API:
$JS.API.STREAM.INFO.<stream> (its "cluster.leader") and
$JS.API.STREAM.MSG.GET.<stream> with {"seq": N, "next_by_subj": S}, answered
by the stream's leader only (as server/cluster/cluster_wal.c reads).
"""
import base64
import json
import random
import re
import socket
import struct
import time

STREAM = "TERRAD_WAL"
SUBJECT_PREFIX = "terrad.wal."


class NatsError(Exception):
    pass


class Conn:
    """One connection; request() sends and waits for the one answer."""

    def __init__(self, host, port, timeout):
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.sock.settimeout(timeout)
        self.buf = b""
        line = self._line()  # INFO {...}: a paused server never sends it (timeout)
        if not line.startswith(b"INFO"):
            raise NatsError(f"expected INFO, got {line[:80]!r}")
        self.inbox = f"_INBOX.chaos{random.getrandbits(48):x}"
        self.sock.sendall(b'CONNECT {"verbose":false,"pedantic":false,"headers":true,'
                          b'"no_responders":true,"protocol":1}\r\nPING\r\n'
                          + f"SUB {self.inbox}.* 1\r\n".encode())
        while self._line() != b"PONG":
            pass
        self.n = 0

    def _fill(self):
        data = self.sock.recv(65536)
        if not data:
            raise NatsError("connection closed")
        self.buf += data

    def _line(self):
        while b"\r\n" not in self.buf:
            self._fill()
        line, self.buf = self.buf.split(b"\r\n", 1)
        return line

    def _take(self, n):
        while len(self.buf) < n + 2:
            self._fill()
        data, self.buf = self.buf[:n], self.buf[n + 2:]
        return data

    def request(self, subject, payload):
        self.n += 1
        reply = f"{self.inbox}.{self.n}"
        body = payload.encode()
        self.sock.sendall(f"PUB {subject} {reply} {len(body)}\r\n".encode() + body + b"\r\n")
        while True:
            line = self._line()
            if line == b"PING":
                self.sock.sendall(b"PONG\r\n")
                continue
            parts = line.split()
            if not parts or parts[0] in (b"PONG", b"+OK"):
                continue
            if parts[0] == b"-ERR":
                raise NatsError(line.decode(errors="replace"))
            if parts[0] == b"MSG":
                data = self._take(int(parts[-1]))
                hdr = b""
            elif parts[0] == b"HMSG":
                total, hlen = int(parts[-1]), int(parts[-2])
                raw = self._take(total)
                hdr, data = raw[:hlen], raw[hlen:]
            else:
                continue
            if parts[1].decode() != reply:
                continue  # an answer to an earlier request that timed out
            if hdr.startswith(b"NATS/1.0 503"):
                raise NatsError("no responders")
            return data

    def close(self):
        try:
            self.sock.close()
        except OSError:
            pass


def connect(urls, timeout=2.0):
    """A connection to the first of urls ("nats://127.0.0.1:P,...") that answers."""
    errors = []
    for url in urls.split(","):
        host, port = url.replace("nats://", "").rsplit(":", 1)
        try:
            return Conn(host, int(port), timeout)
        except (OSError, NatsError) as e:
            errors.append(f"{url}: {e}")
    raise NatsError("no NATS server answers: " + "; ".join(errors))


def api(conn, what, payload="", attempts=20):
    """A JetStream API request's JSON answer; retried while the stream has no
    leader (no responders, a timeout) for up to `attempts` tries."""
    last = None
    for _ in range(attempts):
        try:
            doc = json.loads(conn.request(f"$JS.API.{what}", payload))
            err = doc.get("error")
            if err and err.get("code") == 503:
                last = err
                time.sleep(0.25)
                continue
            return doc
        except (socket.timeout, NatsError) as e:
            last = e
            time.sleep(0.25)
    raise NatsError(f"{what}: {last}")


def stream_leader(urls):
    """The server name of TERRAD_WAL's leader, or None."""
    try:
        conn = connect(urls)
    except NatsError:
        return None
    try:
        return api(conn, f"STREAM.INFO.{STREAM}", attempts=4).get("cluster", {}).get("leader")
    except NatsError:
        return None
    finally:
        conn.close()


def streams_current(urls, streams=(STREAM, "KV_TERRAD_TILES", "KV_TERRAD_LEASES")):
    """1 when each of streams has a leader and every replica is current (caught
    up with it): a NATS server killed and started again has caught up."""
    try:
        conn = connect(urls)
    except NatsError:
        return False
    try:
        for name in streams:
            cl = api(conn, f"STREAM.INFO.{name}", attempts=2).get("cluster", {})
            if not cl.get("leader") or not all(r.get("current") for r in cl.get("replicas", [])):
                return False
        return True
    except NatsError:
        return False
    finally:
        conn.close()


def read_log(urls, world, from_seq):
    """The world's log from sequence from_seq: a list of (seq, kind, tick or
    node) — kind "record" (tick: the record's tick, from its TRC1/TRC2
    header; a record in parts counts once, at its first part), "owner" (node:
    the owner marker's node) or "confirm" (node: the node whose take it
    confirms). Raises NatsError when no leader answers."""
    conn = connect(urls)
    out = []
    try:
        seq = max(1, from_seq)
        while True:
            doc = api(conn, f"STREAM.MSG.GET.{STREAM}",
                      json.dumps({"seq": seq, "next_by_subj": SUBJECT_PREFIX + world}))
            err = doc.get("error")
            if err:
                if err.get("err_code") == 10037 or err.get("code") == 404:
                    return out  # no message at or after seq
                raise NatsError(f"reading the log of {world}: {err}")
            m = doc["message"]
            seq = m["seq"]
            hdrs = base64.b64decode(m.get("hdrs") or "").decode(errors="replace")
            data = base64.b64decode(m.get("data") or "")
            kind = re.search(r"Terrad-Kind: *(owner|confirm)\r", hdrs)
            if kind:
                out.append((seq, kind.group(1), data.decode(errors="replace")))
            elif "Terrad-Part:" not in hdrs or "Terrad-Part: 1/" in hdrs:
                if len(data) < 12 or data[:3] != b"TRC":
                    raise NatsError(f"log of {world}: sequence {seq} is not a record")
                out.append((seq, "record", struct.unpack_from("<Q", data, 4)[0]))
            seq += 1
    finally:
        conn.close()
