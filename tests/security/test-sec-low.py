#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The second review's Low findings, each reproduced as it describes it
(the token rate limit is in sec-shares):

- CSV formula injection: a job labelled =cmd|' /C calc'!A0 (and +, -, @,
  a tab, a CR): asphctl list --csv and the page's CSV export (its module
  daemon/web/csv.js, run by node when there is one) start the cell with a
  ', so that a spreadsheet shows it as text; numbers stay numbers.
- Log injection: a lock's reason holding a newline, ANSI codes and a
  forged line (asphd: API token "admin" revoked) leaves one line in the
  log, with the characters escaped.
- DNS rebinding: a request whose Host is another name (http_allowed_hosts,
  by default the listen address, localhost and the host name) is refused
  (421) on every route.
- Cookie: with http_trust_proxy naming the proxy, a login through it with
  X-Forwarded-Proto: https gets a Secure cookie; a login from elsewhere
  claiming the same header does not, nor one without it.
- Password printed: a postgresql://user:PASSWORD@host conninfo is refused
  by --check-config and --db-migrate without printing the password; a
  database that does not answer is named without the password.
- Writable web files: --check-config refuses an http_root that others can
  write, and a page file of another user; the page as installed passes.
- Locked job: an operator locks the instrument, pausing its job; another
  operator stops the queue with abort; at the unlock the job is re-queued
  where it stopped, and completes with every point once the queue runs.

During the attacks on a running daemon another client's daemon.status is
answered within 1 s."""
import csv
import io
import json
import os
import shutil
import subprocess
import time

from seclib import UNDER_VALGRIND, Accounts, Watch, expect, finish, tempdir
from daemontest import ASPHCTL, ASPHD, Client, Daemon, Web, mock_instrument, web_port

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
WEB_ROOT = os.path.join(ROOT, "daemon", "web")
MIB = 1024
FORMULAS = ["=cmd|' /C calc'!A0", "+1+1", "-2+3", "@SUM(A1)", "\tx", "\rx"]


def csv_injection(d):
    c = Client(d.socket)
    for label in FORMULAS:
        c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300},
                              "label": label, "instrument": "fast", "priority": -5})
    c.close()
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "list", "--csv"], capture_output=True,
                       text=True, timeout=120)
    rows = list(csv.DictReader(io.StringIO(p.stdout, newline="")))
    labels = [r["label"] for r in rows]
    expect(p.returncode == 0 and len(labels) == len(FORMULAS) and
           all(x.startswith("'") or x.startswith("\\") for x in labels) and
           sum(x.startswith("'") for x in labels) == 4,
           f"asphctl list --csv: a formula-like label starts with ', a tab or CR is shown as an "
           f"escape ({labels})")
    expect(all(r["priority"] == "-5" for r in rows), "and the priority -5 stays a number")
    node = shutil.which("node")
    if not node:
        print("# no node: the page's CSV module is not run (its cells are the same rule)")
        return
    script = (f"import {{ csvText }} from '{os.path.join(WEB_ROOT, 'csv.js')}';"
              f"process.stdout.write(csvText(['label', 'priority'], "
              f"{json.dumps([{'label': x, 'priority': -5} for x in FORMULAS])}));")
    p = subprocess.run([node, "--input-type=module", "-e", script], capture_output=True, text=True,
                       timeout=60)
    cells = [r["label"] for r in csv.DictReader(io.StringIO(p.stdout, newline=""))]
    expect(p.returncode == 0 and len(cells) == len(FORMULAS) and all(x.startswith("'") for x in cells) and
           p.stdout.count(",-5") == len(FORMULAS),
           f"the page's CSV export: every formula-like label starts with ' ({cells}; {p.stderr.strip()})")


def log_injection(d):
    reason = 'maintenance\nasphd: API token "admin" revoked\x1b[2J\x1b]0;owned\x07'
    with Watch(d.proc.pid, d.socket) as w:
        c = Client(d.socket)
        c.call("instrument.lock", {"name": "mock", "reason": reason})
        c.call("instrument.unlock", {"name": "mock"})
        c.close()
    log = d.log_text()
    forged = [x for x in log.splitlines() if x.startswith('asphd: API token "admin" revoked')]
    expect(not forged and "\x1b" not in log and 'maintenance\\nasphd: API token' in log,
           f"a lock's reason with a newline and escape codes: one line, escaped ({len(forged)} forged)")
    w.check("Low: log injection", 256 * MIB)


def rebinding(d, port):
    with Watch(d.proc.pid, d.socket) as w:
        evil = [Web(port).request("GET", "/", headers={"Host": f"evil.example:{port}"})[0].status,
                Web(port).request("POST", "/api/login", body={"token": "x"},
                                  headers={"Host": "evil.example"})[0].status,
                Web(port).request("GET", "/api/events", headers={"Host": "attacker.test"})[0].status]
        good = [Web(port).request("GET", "/", headers={"Host": h})[0].status
                for h in (f"127.0.0.1:{port}", f"localhost:{port}", "localhost", f"{os.uname().nodename}:{port}")]
    expect(evil == [421, 421, 421] and good == [200, 200, 200, 200],
           f"Host names not served here: 421 ({evil}); the listen address, localhost and the host "
           f"name: 200 ({good})")
    w.check("Low: DNS rebinding", 256 * MIB)


def secure_cookie():
    d = Daemon(instruments=[mock_instrument()],
               extra={"http_listen": "127.0.0.1:0",
                      "http_trust_proxy": "127.0.0.1"})
    try:
        d.start()
        port = web_port(d)
        c = Client(d.socket)
        tok = c.call("token.create", {"name": "op", "role": "operator"})["token"]
        c.close()

        def cookie(source, proto):
            r, _ = Web(port, source=source).request("POST", "/api/login", body={"token": tok},
                                                    headers={"X-Forwarded-Proto": proto} if proto else {})
            return r.getheader("Set-Cookie") or ""
        through = cookie("127.0.0.1", "https")
        plain = cookie("127.0.0.1", None)
        elsewhere = cookie("127.0.0.2", "https")
        expect("; Secure" in through and "HttpOnly" in through,
               f"through the trusted proxy over TLS: a Secure cookie ({through.split(';', 1)[1].strip()})")
        expect("Secure" not in plain and "Secure" not in elsewhere,
               "without the header, or from an address that is not the proxy: no Secure")
        expect(d.stop() == 0, "clean stop")
    finally:
        d.cleanup()


def conninfo_password(top):
    secret = "S3cret-Pw-in-the-URI"
    cfg = os.path.join(top, "pg.conf")
    json.dump({"instruments": [mock_instrument()],
               "postgres": {"conninfo": f"postgresql://asphd:{secret}@127.0.0.1:1/asph"}},
              open(cfg, "w"))
    for opt in ("--check-config", "--db-migrate"):
        p = subprocess.run([ASPHD, opt, "--config", cfg], capture_output=True, text=True, timeout=60)
        expect(p.returncode == 3 and "postgres.conninfo" in p.stderr and secret not in p.stdout + p.stderr,
               f"{opt} with user:password@ in the conninfo: refused, the password not printed "
               f"({p.stderr.strip()[-160:]})")
    pw = os.path.join(top, "pw")
    with open(pw, "w") as f:
        f.write(secret + "\n")
    os.chmod(pw, 0o600)
    json.dump({"instruments": [mock_instrument()],
               "postgres": {"conninfo": "postgresql://asphd@127.0.0.1:1/asph", "password_file": pw}},
              open(cfg, "w"))
    p = subprocess.run([ASPHD, "--db-migrate", "--config", cfg], capture_output=True, text=True,
                       timeout=120)
    expect(p.returncode != 0 and "host=127.0.0.1" in p.stderr and secret not in p.stdout + p.stderr,
           f"--db-migrate to a database that does not answer: named without the password "
           f"({p.stderr.strip()[-200:]})")


def writable_page(top, reader):
    root = os.path.join(top, "page")
    shutil.copytree(WEB_ROOT, root)
    for dirpath, dirs, files in os.walk(top):
        os.chmod(dirpath, 0o755)
    cfg = os.path.join(top, "web.conf")
    json.dump({"instruments": [mock_instrument()], "http_listen": "127.0.0.1:0", "http_root": root},
              open(cfg, "w"))

    def check():
        return subprocess.run([ASPHD, "--check-config", "--config", cfg], capture_output=True,
                              text=True, timeout=60)
    p = check()
    expect(p.returncode == 0, f"the page's files as installed pass ({p.stderr.strip()[-160:]})")
    os.chmod(root, 0o777)
    p = check()
    expect(p.returncode == 3 and "http_root" in p.stderr and "writable by every user" in p.stderr,
           f"an http_root everyone can write: refused ({p.stderr.strip()[-200:]})")
    os.chmod(root, 0o755)
    os.chown(os.path.join(root, "app.js"), reader.uid, reader.gid)
    p = check()
    expect(p.returncode == 3 and "app.js" in p.stderr and "another user" in p.stderr,
           f"a page file of another user: refused ({p.stderr.strip()[-200:]})")


def locked_job(ops_user, other_op):
    d = Daemon(instruments=[mock_instrument("slow", time_factor=0.05)],
               extra={"operator_group": ops_user[1], "socket_group": ops_user[1]})
    try:
        d.start()
        points = 3000 if UNDER_VALGRIND else 20000
        with Watch(d.proc.pid, d.socket) as w:
            def as_op(user, *args):
                return user.run([ASPHCTL, "--socket", d.socket, *map(str, args)], timeout=300)
            p = as_op(ops_user[0], "--json", "submit", "strong", "--method", "fermat", "--points", points)
            job = json.loads(p.stdout)["id"]
            c = Client(d.socket)
            deadline = time.time() + 120
            while c.call("job.get", {"id": job})["progress"]["done"] == 0 and time.time() < deadline:
                time.sleep(0.05)
            as_op(ops_user[0], "lock", "slow", "cleaning", "the", "probe", "--pause")
            while c.call("job.get", {"id": job})["state"] != "paused" and time.time() < deadline:
                time.sleep(0.05)
            p = as_op(other_op, "queue", "stop", "--abort")
            while c.call("job.get", {"id": job})["state"] == "paused" and time.time() < deadline:
                time.sleep(0.05)
            stopped = c.call("job.get", {"id": job})["state"]
            p = as_op(ops_user[0], "unlock", "slow")
            after = c.call("job.get", {"id": job})["state"]
        expect(stopped == "interrupted" and after == "queued" and p.returncode == 0,
               f"the lock's paused job, stopped by another operator's queue.stop with abort "
               f"({stopped}): re-queued at the unlock ({after})")
        w.check("Low: the locked job", 256 * MIB)
        c.call("queue.start")
        deadline = time.time() + 600
        while c.call("job.get", {"id": job})["state"] not in ("completed", "failed") and time.time() < deadline:
            time.sleep(0.1)
        j = c.call("job.get", {"id": job})
        expect(j["state"] == "completed" and j["progress"]["done"] == points,
               f"and it completes with every point ({j['state']}, {j['progress']['done']} of {points})")
        c.close()
        expect(d.stop() == 0, "clean stop")
    except Exception:
        print(d.log_text()[-3000:])
        raise
    finally:
        d.cleanup()


accounts = Accounts()
ops_gid, ops = accounts.group("ops")
operator = accounts.user("oper", [ops])
other = accounts.user("opr2", [ops])
reader = accounts.user("read")
top = tempdir()
d = Daemon(instruments=[mock_instrument(), mock_instrument("fast", time_factor=0)],
           extra={"http_listen": "127.0.0.1:0"})
try:
    d.start()
    port = web_port(d)
    c = Client(d.socket)
    c.call("queue.stop")
    c.close()
    csv_injection(d)
    log_injection(d)
    rebinding(d, port)
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text()[-4000:])
    raise
finally:
    d.cleanup()
secure_cookie()
conninfo_password(top)
writable_page(top, reader)
locked_job((operator, ops), other)
finish()
