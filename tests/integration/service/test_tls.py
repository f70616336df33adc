#!/usr/bin/python3
"""TLS (issue 15, "Authentication and transport"): with --tls-cert and
--tls-key both ports speak TLS only (libwebsockets' OpenSSL, libmicrohttpd's
GnuTLS). A self-signed certificate made here with `openssl req`: the Python
client (websockets with an ssl context trusting it) and the C client library
(c_client_probe: terrad_client_desc.tls + tls_ca_file) each do hello,
subscribe (whole snapshot) and collider create over wss://, with a driver
token from an auth file; HTTPS /healthz and /v1/world answer through urllib.
A client that trusts another certificate is refused by its own check; plain
ws:// and http:// to the TLS ports fail cleanly and the daemon goes on. A
missing, non-PEM or mismatched certificate or key stops the start with an
error naming the file.
"""
# ctest-timeout: 180
import asyncio
import json
import os
import shutil
import ssl
import subprocess
import sys
import tempfile
import urllib.error
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, skip, tp  # noqa: E402

PROBE = os.environ.get("TERRAD_C_CLIENT_PROBE", os.path.join(os.path.dirname(BIN), "c_client_probe"))


def make_cert(tmp, name):
    cert, key = os.path.join(tmp, name + ".crt"), os.path.join(tmp, name + ".key")
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", key,
                    "-out", cert, "-days", "2", "-subj", "/CN=localhost", "-addext",
                    "subjectAltName=DNS:localhost,IP:127.0.0.1"],
                   check=True, capture_output=True, timeout=60)
    return cert, key


def start_refusals(check, tmp, cert, key, other_key):
    base = [BIN, "serve", "--no-data", "--http-port", "0", "--ws-port", "0", "--backend", "cpu",
            "--no-demo", "--ticks", "2"]
    junk = os.path.join(tmp, "junk.pem")
    with open(junk, "w") as f:
        f.write("not a certificate\n")
    missing = os.path.join(tmp, "missing.crt")
    cases = [
        ("a missing certificate", ["--tls-cert", missing, "--tls-key", key], missing),
        ("a certificate that is not PEM", ["--tls-cert", junk, "--tls-key", key], junk),
        ("a key that is not PEM", ["--tls-cert", cert, "--tls-key", junk], junk),
        ("another certificate's key", ["--tls-cert", cert, "--tls-key", other_key], other_key),
        ("a certificate without a key", ["--tls-cert", cert], "--tls-key"),
    ]
    conf = os.path.join(tmp, "conf.json")
    with open(conf, "w") as f:
        json.dump({"tls_cert": cert, "tls_key": key}, f)
    p = subprocess.run(base + ["--config", conf], capture_output=True, text=True, timeout=60)
    check(p.returncode == 0 and "TLS on both ports" in p.stderr and "https://" in p.stderr,
          f"the config keys tls_cert and tls_key are read ({p.returncode})")
    for what, args, named in cases:
        p = subprocess.run(base + args, capture_output=True, text=True, timeout=60)
        check(p.returncode != 0 and named in p.stderr,
              f"{what} stops the start naming {named} ({p.returncode}): "
              f"{p.stderr.strip().splitlines()[-1:]}")


async def python_client(check, d, ctx, token):
    async with tp.TerradClient(d.ws, token=token, name="tls-python", ssl=ctx) as c:
        check(c.world.get("width", 0) > 0, "Python client: hello over wss:// gets the world")
        sid = await c.subscribe(0, 0, 64, 64)
        await c.wait_complete(sid, timeout=30)
        check(True, "Python client: subscribe and the whole snapshot over wss://")
        cid = await c.create_collider("sphere", radius=0.5)
        seq = await c.send_poses([tp.Pose(cid, 1.0, 1.0, 3.0)])
        await c.wait_ack(seq, timeout=30)
        await c.delete_collider(cid)
        check(True, "Python client: collider created, posed (ACK) and deleted over wss://")
    # plain ws:// to the TLS port: the handshake fails, cleanly
    plain = tp.TerradClient(d.ws.replace("wss://", "ws://"), token=token, name="plain")
    try:
        await asyncio.wait_for(plain.connect(), 20)
        check(False, "plain ws:// to the TLS port is refused")
    except Exception as e:  # noqa: BLE001
        check(True, f"plain ws:// to the TLS port is refused ({type(e).__name__})")
    # a client trusting another certificate refuses the server's
    other = ssl.create_default_context(cafile=d.other_cert)
    wrong = tp.TerradClient(d.ws, token=token, name="wrong-ca", ssl=other)
    try:
        await asyncio.wait_for(wrong.connect(), 20)
        check(False, "a client trusting another certificate refuses the server")
    except ssl.SSLCertVerificationError:
        check(True, "a client trusting another certificate refuses the server")


def main():
    check = Checks()
    if not shutil.which("openssl"):
        skip("no openssl command to make a certificate (scripts/deps --test)")
    with tempfile.TemporaryDirectory(prefix="terrad-tls-") as tmp:
        cert, key = make_cert(tmp, "server")
        other_cert, other_key = make_cert(tmp, "other")
        start_refusals(check, tmp, cert, key, other_key)
        tokens = os.path.join(tmp, "tokens")
        p = subprocess.run([BIN, "token", "add", "--auth-file", tokens, "--role", "driver",
                            "--name", "tls-driver"], capture_output=True, text=True, timeout=30)
        token = p.stdout.strip()
        d = Daemon(extra=["--no-data", "--tls-cert", cert, "--tls-key", key, "--auth-file",
                          tokens], token=None, name="tls")
        d.other_cert = other_cert
        d.http_token = token
        ctx = d.ssl_context = ssl.create_default_context(cafile=cert)
        with check.running(d):
            check(d.tls and d.ws.startswith("wss://") and d.http.startswith("https://"),
                  f"the daemon says it serves https:// and wss:// ({d.http}, {d.ws})")
            check(d.get("/healthz", token="")[0] == 200, "HTTPS /healthz: 200")
            status, body, _ = d.get("/v1/world")
            check(status == 200 and b'"width"' in body, f"HTTPS /v1/world with a token: {status}")
            check(d.get("/v1/world", token="")[0] == 401, "HTTPS /v1/world without a token: 401")
            try:
                urllib.request.urlopen(d.http.replace("https://", "http://") + "/healthz",
                                       timeout=10)
                check(False, "plain http:// to the HTTPS port fails")
            except (urllib.error.URLError, ConnectionError, OSError) as e:
                check(True, f"plain http:// to the HTTPS port fails ({type(e).__name__})")
            asyncio.run(python_client(check, d, ctx, token))
            for host in ("127.0.0.1", "localhost"):
                r = subprocess.run([PROBE, host, str(d.ws_port), cert, token], capture_output=True,
                                   text=True, timeout=90)
                check(r.returncode == 0 and r.stdout.strip().endswith("ok"),
                      f"C client to {host} over wss://: hello, subscribe, create, delete "
                      f"({r.returncode}): {r.stdout.strip()}")
            r = subprocess.run([PROBE, "127.0.0.1", str(d.ws_port), other_cert, token],
                               capture_output=True, text=True, timeout=90)
            check(r.returncode == 1 and "FAIL connect" in r.stdout,
                  f"C client trusting another certificate does not connect: {r.stdout.strip()}")
            r = subprocess.run([PROBE, "127.0.0.1", str(d.ws_port), "-", token],
                               capture_output=True, text=True, timeout=90)
            check(r.returncode == 1 and "FAIL connect" in r.stdout,
                  "C client over plain ws:// to the TLS port does not connect")
            check(d.alive() and d.get("/healthz", token="")[0] == 200,
                  "the daemon goes on after the refused handshakes")
            r = subprocess.run([PROBE, "127.0.0.1", str(d.ws_port), cert, token],
                               capture_output=True, text=True, timeout=90)
            check(r.returncode == 0, "and still serves wss:// clients")
    check.finish()


if __name__ == "__main__":
    main()
