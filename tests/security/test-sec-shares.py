#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The second review's findings on shares (High 1, Medium 6 to 9, Medium
11 and the Low one on the token rate limit), each reproduced as the review
describes it, with bounded loops on 127.0.0.0/8 (addresses of the test's
own: 127.0.0.2 and on) and the unix socket. During each attack another
client asks daemon.status every 50 ms (answered within 1 s); after it
root and an operator on the socket and an admin on the web page get in;
the daemon's RSS stays under 256 MiB.

- High 1: a viewer token logs in to the web page 300 times from 10
  addresses: a token holds at most limits.max_clients_per_user sessions
  (a new one ends its oldest), an address as many (then 503), and a
  viewer never takes the last limits.reserved_clients.
- Medium 6: slow connections, from 9 addresses, one byte a second
  (slowloris): a connection must bring a request's head within
  limits.auth_timeout_ms (3 s here), and a full listener makes room by
  closing the connection that has waited longest; an admin logs in.
- Medium 7: web sessions subscribe to events and hold no connection: the
  subscriptions count against their token's limits.max_subscriptions_per_user
  from any address, and end with their session when it is unused for
  limits.idle_timeout_ms (a reload sets 4 s) without an event stream.
- Medium 8: a token expires while its web session is open: RPC, the
  result files, the live points and the event stream all end with it;
  the same for a token revoked.
- Medium 9: one wrong login a second from the address real users share
  (a proxy, a NAT): 20 valid admin logins from it all succeed.
- Medium 11: the web listener's connections count in the descriptors'
  budget: with LimitNOFILE= just what the start asks for, the web page
  and the socket full, root still connects.
- Low (token rate limit): the same wrong token from 100 rotating source
  addresses: the answers after the claimed prefix's burst wait.

Under valgrind the bounds on time and memory are not checked."""
import datetime
import json
import os
import socket
import subprocess
import threading
import time

from seclib import (PYTHON, UNDER_VALGRIND, Accounts, Slowloris, Watch, expect, finish, free_port,
                    still_in, tempdir)
from daemontest import Client, Daemon, Web, mock_instrument, web_port

MIB = 1024
RSS = 256 * MIB


def clients(d):
    c = Client(d.socket)
    n = c.call("daemon.status")["clients"]
    c.close()
    return n - 1


def logins(d, port, token, n, addresses):
    with Watch(d.proc.pid, d.socket) as w:
        answers = [Web(port, source=addresses[i % len(addresses)]).login(token)[0].status
                   for i in range(n)]
    return answers, w


def high1(d, port, viewer_token, operator, admin_token):
    before = clients(d)
    addresses = [f"127.0.0.{k}" for k in range(2, 12)]
    answers, w = logins(d, port, viewer_token, 300, addresses)
    held = clients(d) - before
    expect(held <= 32 and answers.count(200) >= 32,
           f"300 logins of a viewer token from 10 addresses: {answers.count(200)} opened, "
           f"{held} held (the token's limits.max_clients_per_user: 32)")
    w.check("High 1: 300 web logins of one viewer token", RSS)
    still_in(d, operator, admin_token, port, "High 1")
    # A viewer never takes the reserved sessions: fill with viewer tokens
    # of their own, from addresses of their own.
    root = Client(d.socket)
    extra = [root.call("token.create", {"name": f"v{i}", "role": "viewer"})["token"] for i in range(8)]
    root.close()
    refused = []
    for i, tok in enumerate(extra):
        for k in range(32):
            r, body = Web(port, source=f"127.0.{i + 1}.{k + 2}").login(tok)
            if r.status == 503:
                refused.append(body.get("error", ""))
    n = clients(d)
    expect(refused and "kept for operators" in refused[0] and n <= 256 - 8,
           f"viewers fill the sessions up to {n} of 256: the last 8 kept ({refused[0] if refused else None})")
    still_in(d, operator, admin_token, port, "High 1, the sessions full")
    return extra


def slowloris(d, port, operator, admin_token):
    slow = Slowloris(port, [f"127.0.5.{a}" for a in range(2, 11)])
    time.sleep(0.5)
    with Watch(d.proc.pid, d.socket) as w:
        t0 = time.monotonic()
        r, body = Web(port).login(admin_token)
        took = time.monotonic() - t0
        time.sleep(4.5)
    expect(r.status == 200, f"{len(slow.socks)} slow connections from 9 addresses: an admin logs in "
           f"({took * 1e3:.0f} ms)")
    w.check("Medium 6: slowloris on the web listener", RSS)
    alive = slow.alive()
    slow.stop()
    expect(alive == 0, f"after limits.auth_timeout_ms (3 s) no slow connection is left ({alive} of "
           f"{len(slow.socks)})")
    still_in(d, operator, admin_token, port, "Medium 6")


def reload_limits(d, **limits):
    with open(d.config) as f:
        cfg = json.load(f)
    cfg["limits"].update(limits)
    with open(d.config, "w") as f:
        json.dump(cfg, f)
    n = d.log_text().count("configuration reloaded")
    d.proc.send_signal(__import__("signal").SIGHUP)
    deadline = time.time() + 60
    while d.log_text().count("configuration reloaded") == n and time.time() < deadline:
        time.sleep(0.05)


def subscriptions(d, port, viewer_token, operator, admin_token):
    reload_limits(d, idle_timeout_ms=4000)
    results = []
    with Watch(d.proc.pid, d.socket) as w:
        for i in range(9):
            v = Web(port, source=f"127.0.2.{i + 2}")
            v.login(viewer_token)
            status, a = v.rpc("events.subscribe")
            results.append(a.get("error", {}).get("data", {}).get("detail") if "error" in a else "ok")
        time.sleep(5.5)
    expect(results.count("ok") == 8 and "max_subscriptions_per_user" in (results[-1] or ""),
           f"9 sessions of a viewer token from 9 addresses subscribe, no connection held: 8 taken, the "
           f"ninth refused ({results[-1]})")
    w.check("Medium 7: subscriptions without a connection", RSS)
    c = [Client(d.socket) for _ in range(64)]
    got = 0
    for x in c:
        try:
            x.call("events.subscribe")
            got += 1
        except Exception:  # noqa: BLE001 - counted below
            pass
    for x in c:
        x.close()
    expect(got == 64, f"after limits.idle_timeout_ms (4 s) without a stream they are gone: root takes "
           f"all 64 subscriptions ({got})")
    still_in(d, operator, admin_token, port, "Medium 7")


def expiry(d, port, operator, admin_token):
    root = Client(d.socket)
    job = root.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300},
                                   "instrument": "fast"})["id"]
    deadline = time.time() + 120
    while root.call("job.get", {"id": job})["state"] != "completed" and time.time() < deadline:
        time.sleep(0.1)
    files = root.call("job.result", {"id": job})["files"]
    name = files.get("residuals") or next(iter(files.values()))
    when = (datetime.datetime.now(datetime.timezone.utc) + datetime.timedelta(seconds=4)) \
        .strftime("%Y-%m-%dT%H:%M:%SZ")
    tok = root.call("token.create", {"name": "soon", "role": "viewer", "expires": when})["token"]
    gone = root.call("token.create", {"name": "gone", "role": "viewer"})["token"]

    def expire():
        time.sleep(max(0.0, datetime.datetime.strptime(when, "%Y-%m-%dT%H:%M:%SZ").replace(
            tzinfo=datetime.timezone.utc).timestamp() - time.time()) + 1.5)

    def revoke():
        root.call("token.revoke", {"name": "gone"})
        time.sleep(0.5)
    for what, token, end in (("expired", tok, expire), ("revoked", gone, revoke)):
        v = Web(port)
        expect(v.login(token)[0].status == 200, f"a token to be {what} logs in")
        stream = http_stream(port, v.cookie)

        def statuses():
            return [v.request("GET", f"/api/jobs/{job}/files/{name}")[0].status,
                    v.request("GET", f"/api/jobs/{job}/points")[0].status, v.rpc("version")[0]]
        before = statuses()
        expect(before == [200, 200, 200], f"before it is {what}: files, points, RPC ({before})")
        end()
        after = statuses()
        ended = stream_ended(stream)
        expect(after == [401, 401, 401] and ended,
               f"once it is {what}: files, points, RPC refused ({after}), the event stream "
               f"ended ({ended})")
    root.close()
    still_in(d, operator, admin_token, port, "Medium 8")


def http_stream(port, cookie):
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    s.sendall(f"GET /api/events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nCookie: {cookie}\r\n\r\n".encode())
    head = b""
    while b"\r\n\r\n" not in head:
        head += s.recv(4096)
    return s


def stream_ended(s):
    """Whether the event stream was closed (its end, or the connection's)."""
    s.settimeout(5)
    data = b""
    try:
        while True:
            chunk = s.recv(4096)
            if not chunk:
                return True
            data += chunk
            if data.endswith(b"0\r\n\r\n"):
                return True
    except socket.timeout:
        return False
    except OSError:
        return True


def shared_address(d, port, operator, admin_token):
    stop = threading.Event()
    wrong = []

    def guesser():
        while not stop.is_set():
            r, _ = Web(port).login("asph_" + "x" * 43)
            wrong.append(r.status)
            stop.wait(1.0)
    g = threading.Thread(target=guesser, daemon=True)
    g.start()
    time.sleep(2)
    with Watch(d.proc.pid, d.socket) as w:
        took = []
        for i in range(20):
            t0 = time.monotonic()
            r, _ = Web(port).login(admin_token)
            took.append((r.status, time.monotonic() - t0))
            time.sleep(0.1)
    stop.set()
    g.join()
    ok = [t for s, t in took if s == 200]
    expect(len(ok) == 20 and (UNDER_VALGRIND or max(ok) < 1.0),
           f"a wrong login a second from the same address ({len(wrong)} sent, all 401: "
           f"{set(wrong) == {401}}): {len(ok)} of 20 admin logins succeed, the slowest in "
           f"{max(t for _, t in took) * 1e3:.0f} ms")
    w.check("Medium 9: a guesser behind the users' address", RSS)


def rotating(d, tcp_port, operator, admin_token, port):
    line = b'{"jsonrpc":"2.0","id":1,"method":"hello","params":{"token":"asph_guessguessguess0000000000000000000000000000"}}\n'
    socks = []
    for k in range(100):
        s = socket.create_connection(("127.0.0.1", tcp_port), timeout=30,
                                     source_address=(f"127.0.3.{k + 2}", 0))
        socks.append(s)
    import select
    t0 = time.monotonic()
    for s in socks:
        s.sendall(line)
    fast, waiting = 0, set(socks)
    while waiting and time.monotonic() - t0 < 1.0:
        ready, _, _ = select.select(list(waiting), [], [], max(0.0, 1.0 - (time.monotonic() - t0)))
        for s in ready:
            if s.recv(4096):
                fast += 1
            waiting.discard(s)
    for s in socks:
        s.close()
    expect(fast <= 5 + 2, f"the same wrong token from 100 source addresses: {fast} answered within 1 s "
           f"(the claimed prefix's burst: 5)")
    still_in(d, operator, admin_token, port, "Low: rotating addresses")


# A reader's connections: argv[2] to the socket argv[1], each answered
# once; held until stdin closes. Prints how many it holds.
HOLD = r'''
import json, socket, sys
held = []
for i in range(int(sys.argv[2])):
    s = socket.socket(socket.AF_UNIX)
    try:
        s.connect(sys.argv[1])
        s.sendall(b'{"jsonrpc":"2.0","id":1,"method":"version"}\n')
        if b"result" not in s.recv(4096):
            break
    except OSError:
        break
    held.append(s)
print(json.dumps(len(held)), flush=True)
sys.stdin.read()
'''


def descriptors(reader, lab):
    """Medium 11, in a daemon of its own under a descriptor limit."""
    if UNDER_VALGRIND:
        print("# under valgrind: the descriptor budget is not checked (valgrind keeps descriptors "
              "of its own under the limit)")
        return
    top = tempdir()
    d = Daemon(instruments=[mock_instrument()], top=top,
               extra={"http_listen": "127.0.0.1:0", "socket_group": lab,
                      "limits": {"max_clients": 16, "max_clients_per_user": 16}})
    # What the start asks for: 16 clients and root's 4, 16 web connections
    # and 16 making room, 64 of its own, 4 per instrument.
    need = 16 + 4 + 16 + 16 + 64 + 4
    d.prefix = ["prlimit", f"--nofile={need}:{need}", "--"]
    hold = None
    try:
        d.start()
        port = web_port(d)
        held = []
        for k in range(64):
            try:
                s = socket.create_connection(("127.0.0.1", port), timeout=5,
                                             source_address=(f"127.0.4.{k + 2}", 0))
                s.sendall(b"GET /style.css HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                held.append(s)
            except OSError:
                pass
        hold = reader.popen([PYTHON, "-c", HOLD, d.socket, "40"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
        readers = json.loads(hold.stdout.readline())
        t0 = time.monotonic()
        c = Client(d.socket, timeout=10)
        ok = c.call("daemon.status")["pid"] == d.proc.pid
        took = time.monotonic() - t0
        fds = len(os.listdir(f"/proc/{d.proc.pid}/fd"))
        expect(ok and "Too many open files" not in d.log_text(),
               f"LimitNOFILE {need}: 64 web connections tried, a reader's 40 ({readers} held): "
               f"{fds} descriptors open; root connects ({took * 1e3:.0f} ms), no descriptor short")
        c.close()
        for x in held:
            x.close()
        expect(d.stop() == 0, "clean stop")
    except Exception:
        print(d.log_text()[-3000:])
        raise
    finally:
        if hold:
            hold.stdin.close()
            hold.wait(timeout=60)
        d.cleanup()


accounts = Accounts()
ops_gid, ops = accounts.group("ops")
_, lab = accounts.group("lab")
operator = accounts.user("oper", [lab, ops])
reader = accounts.user("read", [lab])
top = tempdir()
os.mkdir(os.path.join(top, "d"))
tcp_port = free_port()
d = Daemon(instruments=[mock_instrument(), mock_instrument("fast", time_factor=0)],
           top=os.path.join(top, "d"),
           extra={"operator_group": ops, "socket_group": lab, "http_listen": "127.0.0.1:0",
                  "tcp_listen": f"127.0.0.1:{tcp_port}",
                  "limits": {"auth_timeout_ms": 3000, "idle_timeout_ms": 0}})
try:
    d.start()
    port = web_port(d)
    c = Client(d.socket)
    c.call("queue.stop")
    c.call("queue.start")
    tokens = {role: c.call("token.create", {"name": f"t-{role}", "role": role})["token"]
              for role in ("viewer", "admin")}
    c.close()
    shared_address(d, port, operator, tokens["admin"])
    rotating(d, tcp_port, operator, tokens["admin"], port)
    expiry(d, port, operator, tokens["admin"])
    high1(d, port, tokens["viewer"], operator, tokens["admin"])
    slowloris(d, port, operator, tokens["admin"])
    subscriptions(d, port, tokens["viewer"], operator, tokens["admin"])
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text()[-4000:])
    raise
finally:
    d.cleanup()
descriptors(reader, lab)
finish()
