#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Medium 7 and 8 of the security review: the TCP token, and what a reload
applies.

- Guessing: one address sends 2,000 hellos with wrong tokens as fast as it
  can, for 3 s on one connection and then on 20 at once: no more than the
  burst and one guess per 2 s are compared (the rest answered "too many
  wrong tokens" unread), the log says so in a bounded number of lines, and
  the right token is refused as well while the address is held back.
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
    """Wrong hellos pipelined on conns connections for seconds: how many were
    compared ("wrong token") and how many refused unread."""
    socks = [socket.create_connection(("127.0.0.1", port), timeout=30) for _ in range(conns)]
    line = b'{"jsonrpc":"2.0","id":1,"method":"hello","params":{"token":"guess-0000000000000000"}}\n'
    compared = refused = 0
    end = time.monotonic() + seconds
    bufs = [b""] * conns
    while time.monotonic() < end:
        for i, s in enumerate(socks):
            s.sendall(line * 25)
            while bufs[i].count(b"\n") < 25:
                bufs[i] += s.recv(65536)
            for one in bufs[i].split(b"\n")[:25]:
                detail = json.loads(one)["error"]["data"]["detail"]
                compared += detail == "wrong token"
                refused += detail.startswith("too many wrong tokens")
            bufs[i] = b"\n".join(bufs[i].split(b"\n")[25:])
    for s in socks:
        s.close()
    return compared, refused


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
    compared, refused = guess(port, 1, 3.0)
    t1 = time.monotonic()
    rate = compared / (t1 - t0)
    print(f"# one connection, 3 s: {compared + refused} hellos sent, {compared} compared "
          f"({rate:.1f} guesses/s), {refused} refused unread")
    expect(compared <= 5 + 2 and refused > compared, f"at most the burst (5) and one per 2 s compared ({compared})")
    compared2, refused2 = guess(port, 20, 3.0)
    print(f"# 20 connections, 3 s: {compared2 + refused2} hellos, {compared2} compared, {refused2} refused unread")
    expect(compared2 <= 2 + 1, f"20 connections of the same address share the limit ({compared2} compared)")
    logged = len(re.findall(r"wrong token in hello", d.log_text()))
    expect(logged == compared + compared2, f"each compared guess is logged ({logged} lines), no more")
    t = Tcp(port)
    r = t.call("hello", {"token": TOKEN})
    expect("too many wrong tokens" in r.get("error", {}).get("data", {}).get("detail", ""),
           "while held back, even the right token is not looked at")
    time.sleep(2.1)
    r = t.call("hello", {"token": TOKEN})
    expect(r.get("result", {}).get("peer", {}).get("operator") is True, "2 s later the right token is taken")

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
    time.sleep(2.1)         # that was a wrong token too: the address waits for its next try
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
