# SPDX-License-Identifier: GPL-3.0-or-later
"""The security reviews' attacks on asphd (issue 27's audit) as background
loads, for the benchmark `daemon` (tests/bench/bench-daemon-attacks.py: the
p99 of daemon.status under each) and the soak (tests/chaos/soak.py
--attacks: all of them in rotation for hours).

Each attack is a function of ctx = {"web": the web port, "tcp": the TCP
port, "viewer": a viewer's token} that returns the Load threads to start;
setting a Load's .done stops it. ATTACKS is the one list of them, in the
order the benchmark reports."""
import json
import os
import socket
import sys
import threading

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
from daemontest import Web  # noqa: E402
from seclib import Slowloris  # noqa: E402

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
