#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Named API tokens and roles over TCP (docs/daemon.md, "Users, roles and
API tokens"): a viewer's, an operator's and an admin's token against every
documented method; the secret shown once and kept only as its SHA-256;
an expired and a revoked token refused, and the connections that sent
them closed; changes attributed to the token's name in the job history;
the deprecated token_file as one admin token; asphctl token create, list,
revoke."""
import hashlib
import json
import os
import socket
import sqlite3
import subprocess
import time
from datetime import datetime, timedelta, timezone

from daemontest import (ASPHCTL, Client, Daemon, RpcError, documented_methods, expect, finish,
                        free_port, method_params)

SPEC = {"lens": "strong", "plan": {"method": "fermat", "points": 300}}


class TcpClient(Client):
    """The JSON-RPC client over TCP."""

    def __init__(self, port, timeout=30):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        self.buf = b""
        self.next_id = 0
        self.events = []


def connect(port, token):
    c = TcpClient(port)
    return c, c.call("hello", {"client": "test", "token": token})


def refused_hello(port, token):
    c = TcpClient(port)
    try:
        return c.call_error("hello", {"client": "test", "token": token})
    finally:
        c.close()


def closed(c):
    """Whether the daemon closed the connection (within 10 s)."""
    try:
        c.sock.settimeout(10)
        c.call("daemon.status")
        return False
    except (EOFError, OSError):
        return True


port = free_port()
d = Daemon(extra={"tcp_listen": f"127.0.0.1:{port}"})
try:
    d.start()
    root = Client(d.socket)
    root.call("queue.stop")
    tokens = {role: root.call("token.create", {"name": f"{role}-1", "role": role})
              for role in ("viewer", "operator", "admin")}
    expect(all(t["token"].startswith("asph_") and len(t["token"]) == 48 for t in tokens.values()),
           "token.create shows the secret: asph_ and 43 characters")
    listed = root.call("token.list")["tokens"]
    expect(len(listed) == 3 and all("token" not in t for t in listed) and
           {t["name"]: t["role"] for t in listed} == {"viewer-1": "viewer", "operator-1": "operator",
                                                      "admin-1": "admin"},
           "token.list shows names and roles, never a secret")
    store = b""
    for name in ("jobs.sqlite", "jobs.sqlite-wal"):
        try:
            with open(os.path.join(d.state, name), "rb") as f:
                store += f.read()
        except FileNotFoundError:
            pass
    expect(not any(t["token"].encode() in store for t in tokens.values()) and
           all(hashlib.sha256(t["token"].encode()).hexdigest().encode() in store or
               hashlib.sha256(t["token"].encode()).digest() in store for t in tokens.values()),
           "the store keeps each token's SHA-256, never the token")

    # --- every documented method, for each role's token over TCP
    methods = documented_methods()
    needs = {r: {m for m, n in methods.items() if n == r} for r in ("viewer", "operator", "admin")}
    refusable = {"viewer": needs["operator"] | needs["admin"], "operator": needs["admin"],
                 "admin": set()}
    for role in ("viewer", "operator", "admin"):
        job = root.call("job.submit", SPEC)["id"]
        c, hello = connect(port, tokens[role]["token"])
        expect(hello["peer"]["role"] == role and hello["peer"]["token"] == f"{role}-1",
               f"hello with the {role}'s token: role {role}, token named")
        refused = set()
        for m in sorted(methods):
            if m == "hello":
                continue
            if c.call_error(m, method_params(m, job, SPEC)) == 100:
                refused.add(m)
        expect(refused == refusable[role],
               f"the {role}'s token is refused exactly {sorted(refusable[role]) or 'nothing'} "
               f"({sorted(refused)})")
        c.close()
        if root.call("instrument.status", {"name": "mock"})["lock"]:
            root.call("instrument.unlock", {"name": "mock", "force": True})
    expect(refused_hello(port, "asph_" + "A" * 43) == 100, "an unknown token is refused")
    c = TcpClient(port)
    expect(c.call_error("daemon.status") == 100, "a TCP peer without hello is refused")
    c.close()

    # --- changes are the token's in the history
    c, _ = connect(port, tokens["operator"]["token"])
    job = c.call("job.submit", dict(SPEC, label="by token"))["id"]
    c.call("job.cancel", {"id": job})
    hist = root.call("job.get", {"id": job, "history": True})["history"]
    expect([h["actor"] for h in hist] == ["operator-1", "operator-1"],
           f"the history names the token for each change ({[(h['state'], h['actor']) for h in hist]})")
    expect(root.call("job.get", {"id": job})["submitter"]["name"] == "operator-1",
           "the job's submitter is the token's name")

    # --- revoked: refused, and its connection closed
    v, _ = connect(port, tokens["viewer"]["token"])
    root.call("token.revoke", {"name": "viewer-1"})
    expect(closed(v), "revoking a token closes the connections that sent it")
    expect(refused_hello(port, tokens["viewer"]["token"]) == 100, "a revoked token is refused")
    expect(root.call_error("token.revoke", {"name": "viewer-1"}) == 103,
           "revoking it again: 103")
    expect(root.call_error("token.create", {"name": "viewer-1", "role": "viewer"}) == -32602,
           "a revoked token's name is not reused")

    # --- expired: refused, and its connection closed at the expiry
    # seconds to the expiry: enough for a hello and a call, under valgrind too
    life = 10 if os.environ.get("ASPH_UNDER_VALGRIND") else 3
    soon = (datetime.now(timezone.utc) + timedelta(seconds=life)).strftime("%Y-%m-%dT%H:%M:%SZ")
    short = root.call("token.create", {"name": "short", "role": "viewer", "expires": soon})
    s, _ = connect(port, short["token"])
    expect(not closed(s), "a token before its expiry works")
    time.sleep(life + 1.5)
    expect(closed(s), "at its expiry the token's connections are closed")
    expect(refused_hello(port, short["token"]) == 100, "an expired token is refused")
    states = {t["name"]: t["state"] for t in root.call("token.list")["tokens"]}
    expect(states["short"] == "expired" and states["viewer-1"] == "revoked" and
           states["admin-1"] == "active", f"token.list shows the states ({states})")
    past = root.call_error("token.create", {"name": "past", "role": "viewer",
                                            "expires": "2001-01-01"})
    expect(past == -32602, "an expiry in the past is refused")

    # --- a restart keeps the tokens
    root.close()
    expect(d.stop() == 0, "clean stop")
    d.start()
    root = Client(d.socket)
    c, hello = connect(port, tokens["admin"]["token"])
    expect(hello["peer"]["role"] == "admin", "after a restart the admin token works")
    expect(refused_hello(port, tokens["viewer"]["token"]) == 100, "and the revoked one is refused")
    c.close()

    # --- asphctl token
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "--json", "token", "create", "mes",
                        "--role", "operator", "--expires", "30d"], capture_output=True, text=True)
    made = json.loads(p.stdout) if p.returncode == 0 else {}
    expect(made.get("role") == "operator" and made.get("token", "").startswith("asph_"),
           f"asphctl token create --role operator --expires 30d ({p.stderr.strip()})")
    c, hello = connect(port, made["token"])
    expect(hello["peer"]["role"] == "operator", "the token asphctl made works")
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "token", "list"], capture_output=True,
                       text=True)
    expect(p.returncode == 0 and "mes" in p.stdout and made["token"] not in p.stdout,
           "asphctl token list names it, without the secret")
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "token", "revoke", "mes"],
                       capture_output=True, text=True)
    expect(p.returncode == 0 and closed(c), "asphctl token revoke: its connection is closed")
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "token", "create", "x", "--role", "king"],
                       capture_output=True, text=True)
    expect(p.returncode != 0 and p.stderr.strip(), f"a bad role is refused ({p.stderr.strip()})")
    root.close()
    expect(d.stop() == 0, "clean stop")

    # --- the deprecated token file: one admin token named token_file
    secret = "kW3v9QxT2mLp8ZrB4nYc"
    path = os.path.join(d.top, "token")
    with open(path, "w") as f:
        f.write(secret + "\n")
    os.chmod(path, 0o600)
    cfg = json.load(open(d.config))
    cfg["token_file"] = path
    with open(d.config, "w") as f:
        json.dump(cfg, f)
    mark = len(d.log_text())
    d.start()
    c, hello = connect(port, secret)
    expect(hello["peer"]["role"] == "admin" and hello["peer"]["token"] == "token_file",
           "the token file's token is an admin token named token_file")
    job = c.call("job.submit", SPEC)["id"]
    c.call("job.cancel", {"id": job})
    expect(Client(d.socket).call("job.get", {"id": job, "history": True})["history"][-1]["actor"]
           == "token_file", "its changes are attributed to token_file")
    expect("deprecated" in d.log_text()[mark:], "the log says the token file is deprecated")
    c.close()
    expect(d.stop() == 0, "clean stop")
except RpcError as e:
    print(d.log_text()[-3000:])
    raise e
finally:
    d.cleanup()
finish()
