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
import os
import socket
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
sys.path.insert(0, os.path.join(HERE, "..", "security"))
from daemontest import Client, Daemon, free_port, mock_instrument, web_port  # noqa: E402
from seclib import seed_jobs  # noqa: E402
from attacks import ATTACKS  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(HERE, "..", ".."))
SECONDS = float(os.environ.get("ASPH_BENCH_SECONDS", "5"))
JOBS = 10000
TARGET_MS = 50


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
