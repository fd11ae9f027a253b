#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asphd under the security reviews' attacks (tests/security, sec-loop and
sec-shares), each as background load for a few seconds, while one client
asks daemon.status back to back on the unix socket: the p50, p99 and worst
of its answers under each, and with no attack first (the baseline of the
same run). Target: p99 <= 50 ms under every attack.

The daemon has 10,000 jobs queued (the queue stopped) and its web page;
the attackers are a viewer's token over the web page and over TCP, and
connections from addresses of their own in 127.0.0.0/8.

Environment: ASPHD_BIN (the daemon), ASPH_SOURCE_ROOT (the tree: the page's
files), ASPH_BENCH_SECONDS (each attack, default 5)."""
import json
import os
import socket
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
sys.path.insert(0, os.path.join(HERE, "..", "security"))
from daemontest import Client, Daemon, Web, free_port, mock_instrument, web_port  # noqa: E402
from seclib import Slowloris, seed_jobs  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(HERE, "..", ".."))
SECONDS = float(os.environ.get("ASPH_BENCH_SECONDS", "5"))
JOBS = 10000
TARGET_MS = 50
Q2D = {"type": "q2d", "R": 50, "norm_radius": 10, "aperture_diameter": 20, "a": [0.001] * 5,
       "a_m": {str(m): [1e-4] * 21 for m in range(1, 21)}}


class Load(threading.Thread):
    """An attack: body() again and again until stopped."""

    def __init__(self, body):
        super().__init__(daemon=True)
        self.body, self.done = body, threading.Event()

    def run(self):
        while not self.done.is_set():
            try:
                self.body(self.done)
            except Exception:  # noqa: BLE001 - an attack that fails goes on
                self.done.wait(0.05)


def status_latencies(path, seconds):
    """daemon.status back to back on one connection for seconds."""
    s = socket.socket(socket.AF_UNIX)
    s.connect(path)
    req = b'{"jsonrpc":"2.0","id":1,"method":"daemon.status"}\n'
    lat, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        t0 = time.monotonic()
        s.sendall(req)
        buf = b""
        while not buf.endswith(b"\n"):
            buf += s.recv(65536)
        lat.append(time.monotonic() - t0)
    s.close()
    return sorted(lat)


def tcp_viewer(port, token):
    s = socket.create_connection(("127.0.0.1", port), timeout=60)
    f = s.makefile("rwb")
    f.write(json.dumps({"jsonrpc": "2.0", "id": 0, "method": "hello", "params": {"token": token}}).encode() + b"\n")
    f.flush()
    f.readline()
    return s, f


def call(f, method, params):
    f.write(json.dumps({"jsonrpc": "2.0", "id": 1, "method": method, "params": params}).encode() + b"\n")
    f.flush()
    return f.readline()


# --- the attacks: each a function that sets up loads and returns them

def web_batch(ctx):
    v = Web(ctx["web"])
    v.login(ctx["viewer"])
    raw = json.dumps([{"jsonrpc": "2.0", "method": "queue.get"}] * 80).encode()
    return [Load(lambda done: v.request("POST", "/api/rpc", raw=raw,
                                        headers={"Content-Type": "application/json"}))]


def estimates(ctx):
    loads = []
    for params in ({"lens": Q2D, "plan": {"method": "ci", "points": 300000}},
                   {"lens": Q2D, "plan": {"method": "ci", "points": 200}},
                   {"lens": "strong", "plan": {"method": "fermat", "points": 4900000}}):
        def body(done, params=params):
            s, f = tcp_viewer(ctx["tcp"], ctx["viewer"])
            while not done.is_set():
                call(f, "job.estimate", params)
            s.close()
        loads.append(Load(body))
    return loads


def socket_notifications(ctx):
    line = (json.dumps([{"jsonrpc": "2.0", "method": "job.list", "params": {"limit": 1000}}] * 1000)
            + "\n" + json.dumps({"jsonrpc": "2.0", "id": 2, "method": "version"}) + "\n").encode()

    def body(done):
        s, f = tcp_viewer(ctx["tcp"], ctx["viewer"])
        while not done.is_set():
            f.write(line)
            f.flush()
            f.readline()
        s.close()
    return [Load(body)]


def never_read(ctx):
    held = []

    def body(done):
        for k in range(32):
            s = socket.create_connection(("127.0.0.1", ctx["tcp"]), timeout=60,
                                         source_address=(f"127.0.6.{k + 2}", 0))
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.sendall(json.dumps({"jsonrpc": "2.0", "id": 0, "method": "hello",
                                  "params": {"token": ctx["viewer"]}}).encode() + b"\n" +
                      b'{"jsonrpc":"2.0","id":1,"method":"queue.get"}\n')
            held.append(s)
        done.wait()
        for s in held:
            s.close()
    return [Load(body)]


def logins(ctx):
    def body(done):
        for k in range(300):
            if done.is_set():
                return
            Web(ctx["web"], source=f"127.0.7.{k % 10 + 2}").login(ctx["viewer"])
    return [Load(body)]


def slowloris(ctx):
    def body(done):
        slow = Slowloris(ctx["web"], [f"127.0.8.{a}" for a in range(2, 11)])
        done.wait()
        slow.stop()
    return [Load(body)]


def wrong_tokens(ctx):
    def body(done):
        Web(ctx["web"]).login("asph_" + "x" * 43)
    return [Load(body) for _ in range(8)]


ATTACKS = [
    ("no attack (baseline)", lambda ctx: []),
    ("High 2: web batches of 80 queue.get notifications", web_batch),
    ("High 3: estimates (Q2D ci, strong 4.9 M points)", estimates),
    ("Medium 4: batches of 1,000 job.list notifications", socket_notifications),
    ("Medium 5: 32 clients that never read 6 MB answers", never_read),
    ("High 1: 300 web logins of one viewer token", logins),
    ("Medium 6: slowloris, 288 connections from 9 addresses", slowloris),
    ("Medium 9: wrong tokens from 8 connections", wrong_tokens),
]


def main():
    tcp = free_port()
    d = Daemon(instruments=[mock_instrument()],
               extra={"http_listen": "127.0.0.1:0", "http_root": os.path.join(ROOT, "daemon", "web"),
                      "tcp_listen": f"127.0.0.1:{tcp}",
                      "limits": {"max_queue": 2 * JOBS, "request_timeout_ms": 5000}})
    misses = 0
    try:
        seed_jobs(d, JOBS, 0)
        d.start()
        c = Client(d.socket)
        ctx = {"web": web_port(d), "tcp": tcp,
               "viewer": c.call("token.create", {"name": "bench-viewer", "role": "viewer"})["token"]}
        c.close()
        for what, attack in ATTACKS:
            loads = attack(ctx)
            for load in loads:
                load.start()
            time.sleep(0.5)
            lat = status_latencies(d.socket, SECONDS)
            for load in loads:
                load.done.set()
            for load in loads:
                load.join(timeout=30)
            p = lambda q: lat[min(len(lat) - 1, int(q * (len(lat) - 1)))] * 1e3  # noqa: E731
            verdict = "PASS" if p(0.99) <= TARGET_MS else "MISS"
            misses += verdict == "MISS"
            print(f"daemon.status under {what}: {len(lat)} answers, p50 {p(0.5):.2f} ms, "
                  f"p99 {p(0.99):.2f} ms, max {lat[-1] * 1e3:.1f} ms (target p99 <= {TARGET_MS} ms): "
                  f"{verdict}", flush=True)
            time.sleep(1.0)     # (the attack's connections close)
        d.stop()
    except Exception:
        print(d.log_text()[-3000:])
        raise
    finally:
        d.cleanup()
    return 1 if misses else 0


if __name__ == "__main__":
    sys.exit(main())
