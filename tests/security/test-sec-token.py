#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Medium 7 and 8 of the security review: the TCP token, and what a reload
applies.

- Guessing: one address sends hellos with wrong tokens as fast as it can,
  for 3 s on one connection and then on 20 at once: past the burst of 5,
  the answer to each wrong token waits until the address has earned its
  next try (one per 2 s), so that one connection makes about one guess
  per 2 s and 20 connections of the address about 20; the log says so in
  a bounded number of lines; and the right token, from the same address
  while it is held back (a user behind the guesser's proxy), is taken at
  once: a guesser slows itself down, never the users it shares an address
  with.
- Weak tokens: 16 a's, "0123456789abcdef..." and the like are refused at the
  start (exit 3) with the rule.
- Identity: job.list with mine over TCP gives the jobs submitted over TCP,
  not every job.
- Reload: the token rotated and SIGHUP: a connection that sent the old one
  is closed, the old one is refused, the new one works; socket_mode and
  socket_group are applied to the socket; tcp_listen removed closes the TCP
  listener and its connections; a new tcp_listen address, or changed
  instruments, refuse the whole reload naming them, and everything stays
  as it was."""
import grp
import json
import os
import re
import select
import signal
import socket
import stat
import subprocess
import time

from seclib import UNDER_VALGRIND, Accounts, expect, finish, free_port, tempdir
from daemontest import ASPHD, Client, Daemon, mock_instrument

TOKEN = "Kq8vT2mXw9LpZr4bNc7YhGd3"
ROTATED = "w7RmQ2zXc9VbLk4NpT8sYhJ6"


class Tcp:
    def __init__(self, port):
        self.s = socket.create_connection(("127.0.0.1", port), timeout=30)
        self.f = self.s.makefile("rwb")
        self.n = 0

    def call(self, method, params=None):
        self.n += 1
        msg = {"jsonrpc": "2.0", "id": self.n, "method": method}
        if params is not None:
            msg["params"] = params
        self.f.write(json.dumps(msg).encode() + b"\n")
        self.f.flush()
        line = self.f.readline()
        if not line:
            raise EOFError("closed")
        return json.loads(line)

    def close(self):
        self.s.close()


def guess(port, conns, seconds):
    """Wrong hellos pipelined on conns connections for seconds: how many
    were answered ("wrong token"), and the longest wait for an answer."""
    socks = [socket.create_connection(("127.0.0.1", port), timeout=30) for _ in range(conns)]
    line = b'{"jsonrpc":"2.0","id":1,"method":"hello","params":{"token":"guess-0000000000000000"}}\n'
    for s in socks:
        s.sendall(line * 25)
    answered, other, longest = 0, 0, 0.0
    last = {s: time.monotonic() for s in socks}
    end = time.monotonic() + seconds
    bufs = {s: b"" for s in socks}
    while time.monotonic() < end:
        ready, _, _ = select.select(socks, [], [], max(0.0, end - time.monotonic()))
        for s in ready:
            bufs[s] += s.recv(65536)
            while b"\n" in bufs[s]:
                one, bufs[s] = bufs[s].split(b"\n", 1)
                now = time.monotonic()
                longest = max(longest, now - last[s])
                last[s] = now
                if json.loads(one)["error"]["data"]["detail"] == "wrong token":
                    answered += 1
                else:
                    other += 1
    for s in socks:
        s.close()
    return answered, other, longest


def set_config(d, **changes):
    cfg = json.load(open(d.config))
    for k, v in changes.items():
        if v is None:
            cfg.pop(k, None)
        else:
            cfg[k] = v
    json.dump(cfg, open(d.config, "w"))


def reload(d):
    mark = len(d.log_text())
    d.proc.send_signal(signal.SIGHUP)
    deadline = time.time() + (60 if UNDER_VALGRIND else 10)
    while time.time() < deadline:
        said = d.log_text()[mark:]
        if "reloaded" in said or "refused" in said or "error" in said:
            return said
        time.sleep(0.05)
    return d.log_text()[mark:]


accounts = Accounts()
_, lab = accounts.group("lab")
_, lab2 = accounts.group("lab2")
top = tempdir()
token = os.path.join(top, "token")


def write_token(text):
    with open(token, "w") as f:
        f.write(text + "\n")
    os.chmod(token, 0o600)


# --- weak tokens are refused at the start
write_token("a" * 16)
for weak in ("a" * 16, "0123456789abcdef0123", "abababababababababab", "passwordpassword"):
    write_token(weak)
    cfg = os.path.join(top, "weak.conf")
    json.dump({"instruments": [mock_instrument()], "tcp_listen": "127.0.0.1:0", "token_file": token},
              open(cfg, "w"))
    p = subprocess.run([ASPHD, "--check-config", "--config", cfg], capture_output=True, text=True, timeout=60)
    expect(p.returncode == 3 and "too easy to guess" in p.stderr and "token_file" in p.stderr,
           f"the token {weak!r} is refused ({p.stderr.strip()[-120:]})")

write_token(TOKEN)
port = free_port()
d = Daemon(instruments=[mock_instrument(time_factor=0)],
           extra={"socket_group": lab, "tcp_listen": f"127.0.0.1:{port}", "token_file": token})
try:
    d.start()
    # --- guessing
    t0 = time.monotonic()
    answered, other, longest = guess(port, 1, 3.0)
    rate = answered / (time.monotonic() - t0)
    print(f"# one connection, 3 s: {answered} wrong tokens answered ({rate:.1f} guesses/s), "
          f"the longest wait {longest:.2f} s")
    expect(5 <= answered <= 5 + 2 and other == 0,
           f"the burst (5) and one per 2 s answered ({answered}), each \"wrong token\"")
    expect(longest > 1.0, f"past the burst an answer waits for the address's next try ({longest:.2f} s)")
    answered2, other2, _ = guess(port, 20, 3.0)
    print(f"# 20 connections, 3 s: {answered2} wrong tokens answered")
    expect(answered2 <= 20 * 2 and other2 == 0,
           f"20 connections of the address: at most one guess per 2 s each ({answered2})")
    logged = len(re.findall(r"wrong token in hello", d.log_text()))
    expect(logged <= 5 + 2 + 2, f"the log holds a bounded number of lines ({logged}), "
           f"each counting those left out")
    # While a wrong token of the address waits for its next try, the right
    # token from the same address is answered first: an order, not a time,
    # so that a loaded machine cannot make it flake.
    held = socket.create_connection(("127.0.0.1", port), timeout=30)
    wrong = b'{"jsonrpc":"2.0","id":1,"method":"hello","params":{"token":"guess-0000000000000000"}}\n'
    held.sendall(wrong)
    held.recv(65536)          # (it takes a try the address may have earned)
    held.sendall(wrong)       # this one waits for the next: about 2 s
    t = Tcp(port)
    t0 = time.monotonic()
    r = t.call("hello", {"token": TOKEN})
    took = time.monotonic() - t0
    first = not select.select([held], [], [], 0)[0]
    held_answer = held.recv(65536)
    waited = time.monotonic() - t0
    held.close()
    expect(r.get("result", {}).get("peer", {}).get("operator") is True and first and
           b"wrong token" in held_answer,
           f"while the address is held back, the right token is taken before the wrong one waiting "
           f"({took * 1e3:.0f} ms, the wrong token {waited * 1e3:.0f} ms)")

    # --- identity over TCP
    local = Client(d.socket)
    mine_local = local.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300}})["id"]
    r = t.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300}})
    mine_tcp = r["result"]["id"]
    ids = [j["id"] for j in t.call("job.list", {"mine": True})["result"]["jobs"]]
    expect(ids == [mine_tcp], f"job.list mine over TCP: the TCP jobs only ({ids}, not {mine_local})")
    expect(r["result"]["submitter"]["name"] == "token_file",
           f"a TCP job names its token (token_file's), not the address "
           f"({r['result']['submitter']['name']})")

    # --- reload: the token rotated
    write_token(ROTATED)
    said = reload(d)
    expect("reloaded" in said, f"the rotated token is reloaded ({said.strip()[-120:]})")
    try:
        r = t.call("version")
        gone = "error" in r and r["error"]["code"] == 100
        t.f.readline()
    except (EOFError, OSError):
        gone = True
    expect(gone, "the connection that sent the old token is closed")
    t.close()
    t = Tcp(port)
    expect(t.call("hello", {"token": TOKEN}).get("error", {}).get("code") == 100, "the old token is refused")
    expect(t.call("hello", {"token": ROTATED}).get("result", {}).get("peer", {}).get("operator"),
           "the new one is taken")

    # --- reload: socket mode and group
    set_config(d, socket_mode="0640", socket_group=lab2)
    said = reload(d)
    st = os.stat(d.socket)
    expect("reloaded" in said and stat.S_IMODE(st.st_mode) == 0o640 and st.st_gid == grp.getgrnam(lab2).gr_gid,
           f"socket_mode and socket_group apply at once ({oct(stat.S_IMODE(st.st_mode))}, gid {st.st_gid})")

    # --- reload refused: a new TCP address, changed instruments
    set_config(d, tcp_listen=f"127.0.0.1:{free_port()}")
    said = reload(d)
    expect("reload refused" in said and "tcp_listen" in said, f"a new tcp_listen: refused, named ({said.strip()[-160:]})")
    set_config(d, tcp_listen=f"127.0.0.1:{port}", instruments=[mock_instrument("other")])
    said = reload(d)
    expect("reload refused" in said and "instruments" in said, f"changed instruments: refused, named ({said.strip()[-160:]})")
    expect(t.call("version").get("result", {}).get("server") == "asphd", "the running configuration is kept")

    # --- reload: tcp_listen removed
    set_config(d, tcp_listen=None, token_file=None, instruments=[mock_instrument(time_factor=0)])
    said = reload(d)
    expect("reloaded" in said, f"tcp_listen removed: reloaded ({said.strip()[-120:]})")
    try:
        r = t.call("version")
        closed = "error" in r
    except (EOFError, OSError):
        closed = True
    expect(closed, "the TCP connection is closed")
    try:
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
        listening = True
    except OSError:
        listening = False
    expect(not listening, "and nothing listens on the port any more")
    expect(local.call("version")["server"] == "asphd", "the unix socket serves on")
    local.close()
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text()[-4000:])
    raise
finally:
    d.cleanup()
finish()
