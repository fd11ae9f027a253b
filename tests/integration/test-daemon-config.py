#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asphd --check-config names every error with its place (the mqtt and
postgres sections and the files they name included); SIGHUP reloads
the limits; the TCP listener needs a token file and a hello with the token;
a state directory writable by everyone is refused."""
import json
import os
import signal
import socket
import subprocess
import time

from daemontest import ASPHD, Client, Daemon, expect, finish, mock_instrument, poll_state, free_port


def check(path):
    p = subprocess.run([ASPHD, "--check-config", "--config", path], capture_output=True, text=True)
    return p.returncode, p.stdout, p.stderr


d = Daemon()
try:
    rc, out, _ = check(d.config)
    expect(rc == 0 and "OK, 1 instrument(s)" in out, "check-config accepts the test configuration")
    bad = os.path.join(d.top, "bad.conf")
    with open(bad, "w") as f:
        f.write('{\n  "socket": "relative",\n  "limits": {"max_clients": 0},\n  "colour": 1\n}\n')
    rc, _, err = check(bad)
    lines = err.strip().splitlines()
    expect(rc == 3 and len(lines) == 3, f"check-config: exit 3, one line per error ({lines})")
    expect(any(f"{bad}:2:" in x and "socket" in x for x in lines), "the socket error names line 2")
    expect(any(f"{bad}:3:" in x and "limits.max_clients" in x for x in lines), "the limit error names line 3")
    expect(any(f"{bad}:4:" in x and "colour" in x for x in lines), "the unknown setting names line 4")
    with open(bad, "w") as f:
        json.dump({"instruments": [{"name": "m", "stage": {"driver": "mock"},
                                    "probe": {"driver": "mock", "options": {"rate": "fast"}}}]}, f, indent=2)
    rc, _, err = check(bad)
    expect(rc == 3 and "rate" in err and f"{bad}:" in err, f"a bad driver option is named with its place ({err.strip()})")
    with open(bad, "w") as f:
        f.write('{"instruments": [ {"name": "m", "stage": {"driver": "nosuch"}}]}')
    rc, _, err = check(bad)
    expect(rc == 3 and "nosuch" in err, "an unknown driver is named")

    # The mqtt and postgres sections: each error named with its place
    cred = os.path.join(d.top, "mqtt-credentials.json")
    with open(cred, "w") as f:
        f.write('{"password": "x", "colour": 1}\n')
    os.chmod(cred, 0o644)
    with open(bad, "w") as f:
        f.write('{\n  "mqtt": {\n    "url": "http://broker:1883",\n    "prefix": "lab/#",\n'
                '    "qos": 3,\n    "retain": true,\n'
                f'    "credentials_file": "{cred}",\n'
                '    "ca_file": "/nonexistent/ca.pem"\n  },\n'
                '  "postgres": {\n    "conninfo": "host=db password=secret",\n'
                '    "password_file": "/nonexistent/pw"\n  }\n}\n')
    rc, _, err = check(bad)
    lines = err.strip().splitlines()
    for line_no, field, what in ((3, "mqtt.url", "mqtt:// or mqtts://"),
                                 (4, "mqtt.prefix", "'#'"),
                                 (5, "mqtt.qos", "qos"),
                                 (6, "mqtt.retain", "unknown setting"),
                                 (11, "postgres.conninfo", "password")):
        expect(rc == 3 and any(f"{bad}:{line_no}:" in x and field in x and what in x.lower() + x
                               for x in lines),
               f"{field}: named at line {line_no} ({[x for x in lines if field in x][:1]})")
    # the files the sections name, once the sections themselves are right
    with open(bad, "w") as f:
        json.dump({"mqtt": {"url": "mqtts://broker.example", "credentials_file": cred,
                            "ca_file": "/nonexistent/ca.pem"},
                   "postgres": {"conninfo": "host=db", "password_file": "/nonexistent/pw"}},
                  f, indent=2)
    rc, _, err = check(bad)
    expect(rc == 3 and "mqtt.credentials_file" in err and "readable by its owner only" in err,
           f"a credentials file others can read is refused ({err.strip()})")
    expect("mqtt.ca_file" in err and "/nonexistent/ca.pem" in err and
           "postgres.password_file" in err and "/nonexistent/pw" in err,
           "a missing CA file and password file are named")
    os.chmod(cred, 0o600)
    with open(bad, "w") as f:
        json.dump({"mqtt": {"url": "mqtt://[::1]:1883", "credentials_file": cred}}, f, indent=2)
    rc, _, err = check(bad)
    expect(rc == 3 and "unknown member \"colour\"" in err and "a password needs a username" in err,
           f"the credentials file's members are checked ({err.strip()})")
    with open(bad, "w") as f:
        json.dump({"mqtt": {"url": "mqtt://[::1:1883"}}, f, indent=2)
    rc, _, err = check(bad)
    expect(rc == 3 and "closing ']'" in err, "an IPv6 address without its ']' is refused")
    with open(bad, "w") as f:
        json.dump({"mqtt": {"prefix": "a/b"}, "postgres": {}}, f)
    rc, _, err = check(bad)
    expect(rc == 3 and "needs \"url\"" in err and "needs \"conninfo\"" in err,
           "mqtt without url and postgres without conninfo are refused")
    with open(bad, "w") as f:
        json.dump({"mqtt": {"url": "mqtts://broker.example:8883", "prefix": "lab/bench-7",
                            "client_id": "bench-7", "qos": 2},
                   "postgres": {"conninfo": "host=db.example dbname=asph user=asphd"}}, f)
    rc, out, err = check(bad)
    expect(rc == 0, f"a valid mqtt and postgres section pass ({err.strip()})")
    p = subprocess.run([ASPHD, "--db-migrate", "--config", d.config], capture_output=True,
                       text=True)
    expect(p.returncode == 3 and "no \"postgres\" section" in p.stderr,
           f"--db-migrate without a postgres section: exit 3 ({p.stderr.strip()})")

    # A JOURNAL_STREAM that is not DEVICE:INODE (decimal) is said; the log
    # stays text on stderr. The configuration error stops asphd right after.
    broken = os.path.join(d.top, "broken.conf")
    with open(broken, "w") as f:
        f.write('{"colour": 1}\n')
    for stream, said in (("12:x", True), ("12", True), (":34", True), ("-1:5", True),
                         ("12: 34", True), ("12:34 ", True), ("99999999999999999999999:1", True),
                         ("1:2", False)):
        p = subprocess.run([ASPHD, "--config", broken], env=dict(os.environ, JOURNAL_STREAM=stream),
                           capture_output=True, text=True)
        expect(p.returncode == 3 and "colour" in p.stderr and
               ("is not DEVICE:INODE" in p.stderr) == said,
               f"JOURNAL_STREAM={stream!r}: {'refused' if said else 'taken'} ({p.stderr.strip()})")

    # --- reload
    d.start()
    c = Client(d.socket)
    expect(c.call("job.list", {"limit": 1})["limit"] == 1, "limits before reload")
    cfg = json.load(open(d.config))
    cfg["limits"] = {"max_queue": 1}
    json.dump(cfg, open(d.config, "w"))
    d.proc.send_signal(signal.SIGHUP)
    time.sleep(0.5)
    c.call("queue.stop")
    c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 200}})
    expect(c.call_error("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 200}}) == 104,
           "after SIGHUP the new queue limit applies")
    with open(d.config, "w") as f:
        f.write("{ broken")
    d.proc.send_signal(signal.SIGHUP)
    time.sleep(0.5)
    expect(c.call("version")["server"] == "asphd" and "keeping the old one" in d.log_text(),
           "a broken configuration is refused on reload; the daemon keeps serving")
    c.close()
    expect(d.stop() == 0, "clean stop")

    # --- TCP with a token
    port = free_port()
    token = os.path.join(d.top, "token")
    with open(token, "w") as f:
        f.write("Kq8vT2mXw9LpZr4bNc7YhGd3\n")
    os.chmod(token, 0o600)
    cfg = {"instruments": [mock_instrument()], "tcp_listen": f"127.0.0.1:{port}", "token_file": token}
    json.dump(cfg, open(d.config, "w"))
    d.start()
    t = socket.create_connection(("127.0.0.1", port), timeout=10)
    tf = t.makefile("rw")

    def tcall(method, params=None):
        tf.write(json.dumps({"jsonrpc": "2.0", "id": 1, "method": method, "params": params or {}}) + "\n")
        tf.flush()
        return json.loads(tf.readline())

    expect(tcall("daemon.status").get("error", {}).get("code") == 100, "TCP: nothing before hello")
    expect(tcall("hello", {"token": "wrong"}).get("error", {}).get("code") == 100, "TCP: a wrong token is refused")
    r = tcall("hello", {"token": "Kq8vT2mXw9LpZr4bNc7YhGd3"})
    expect(r.get("result", {}).get("peer", {}).get("operator") is True, "TCP: the token authenticates an operator")
    expect("result" in tcall("daemon.status"), "TCP: then every method works")
    t.close()
    expect(d.stop() == 0, "clean stop")
    os.chmod(token, 0o644)
    d.start(wait=False)
    expect(d.proc.wait(timeout=30) == 3 and "readable by its owner only" in d.log_text(),
           "a token file others can read is refused (exit 3, a configuration error)")
    d.proc = None
    cfg.pop("token_file")
    json.dump(cfg, open(d.config, "w"))
    d.start()
    t = socket.create_connection(("127.0.0.1", port), timeout=10)
    tf = t.makefile("rw")
    expect(tcall("hello", {"token": "Kq8vT2mXw9LpZr4bNc7YhGd3"}).get("error", {}).get("code") == 100,
           "TCP without token_file: the old token is refused (named tokens only)")
    expect(tcall("daemon.status").get("error", {}).get("code") == 100,
           "TCP without a token: nothing but hello")
    t.close()
    expect(d.stop() == 0, "clean stop")

    # --- socket activation and the notify protocol, as systemd does them
    json.dump({"instruments": [mock_instrument()]}, open(d.config, "w"))
    notify_path = os.path.join(d.top, "notify")
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(notify_path)
    notify.settimeout(10)
    listen_path = os.path.join(d.top, "activated.sock")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(listen_path)
    listener.listen(16)
    lfd = listener.fileno()

    def activate():
        os.dup2(lfd, 3)
        os.environ["LISTEN_FDS"] = "1"
        os.environ["LISTEN_PID"] = str(os.getpid())
        os.environ["NOTIFY_SOCKET"] = notify_path
        os.environ["WATCHDOG_USEC"] = "300000"

    logf = open(d.log, "a")
    proc = subprocess.Popen([ASPHD, "--config", d.config, "--socket", os.path.join(d.top, "unused.sock"),
                             "--state-dir", d.state], stdout=logf, stderr=logf, preexec_fn=activate,
                            pass_fds=(3,) if lfd != 3 else ())
    msgs = []
    deadline = time.time() + 10
    while time.time() < deadline and not any("READY=1" in m for m in msgs):
        msgs.append(notify.recv(4096).decode())
    expect(any("READY=1" in m for m in msgs), "READY=1 is sent")
    expect(any("STATUS=idle" in m for m in msgs), "STATUS= says idle")
    c = Client(listen_path)
    expect(c.call("version")["server"] == "asphd", "the daemon serves the socket systemd passed")
    expect(not os.path.exists(os.path.join(d.top, "unused.sock")), "and binds none of its own")
    c.close()
    pings = 0
    deadline = time.time() + 3
    while time.time() < deadline and pings < 2:
        pings += "WATCHDOG=1" in notify.recv(4096).decode()
    expect(pings >= 2, "the loop pings the watchdog")
    proc.send_signal(signal.SIGTERM)
    stopping = False
    deadline = time.time() + 10
    while time.time() < deadline and not stopping:
        try:
            stopping = "STOPPING=1" in notify.recv(4096).decode()
        except socket.timeout:
            break
    expect(stopping and proc.wait(timeout=30) == 0, "STOPPING=1, then exit 0")
    expect(os.path.exists(listen_path), "an activated socket is left to systemd")
    logf.close()
    notify.close()
    listener.close()

    # --- two instruments measure at once, each one job at a time
    json.dump({"instruments": [mock_instrument("m1"), mock_instrument("m2")]}, open(d.config, "w"))
    d.start()
    c = Client(d.socket)
    c.call("queue.start")   # stopped above; the setting outlives restarts
    spec = {"lens": "strong", "plan": {"method": "ci", "h": 0.04}}
    a = c.call("job.submit", dict(spec, instrument="m1"))["id"]
    b = c.call("job.submit", dict(spec, instrument="m1"))["id"]
    m = c.call("job.submit", dict(spec, instrument="m2"))["id"]
    both = False
    deadline = time.time() + 60
    while time.time() < deadline and not both:
        st = {i: c.call("job.get", {"id": i})["state"] for i in (a, b, m)}
        both = st[a] == "running" and st[m] == "running"
        if both:
            expect(st[b] == "queued", "one job at a time on m1: the second waits")
        time.sleep(0.02)
    expect(both, "m1 and m2 measure at the same time")
    expect(all(poll_state(c, i, ["completed", "failed"])["state"] == "completed" for i in (a, b, m)),
           "all three jobs complete")
    names = {x["name"]: x for x in c.call("instrument.list")["instruments"]}
    expect(set(names) == {"m1", "m2"} and all(x["state"] == "idle" for x in names.values()),
           "both instruments are idle again")
    c.close()
    expect(d.stop() == 0, "clean stop")

    # --- a state directory anyone may write is refused
    os.chmod(d.state, 0o777)
    d.start(wait=False)
    expect(d.proc.wait(timeout=30) == 1 and "writable by every user" in d.log_text(),
           "a world-writable state directory is refused")
    d.proc = None
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
