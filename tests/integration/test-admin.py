#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""docs/admin.md, procedure by procedure, against the real daemon: the
guide's commands are taken from the guide and run as printed, with the
paths of this test's daemon in place of the installed ones (the state
directory, /var/backups/asphd, the socket, the web listener's port), the
test's own user in place of the asphd user, and the test starting and
stopping the daemon where the guide runs systemctl (no systemd runs here).

- Backup and restore: `asphctl backup` while a job runs and a second
  client asks daemon.status (the copy is of one moment, the job goes on,
  nobody waits), the copy checked with SQLite, the folders with tar; the
  restore as printed, and what the guide says of the restored daemon
  (the running job interrupted and resumable, later jobs and tokens gone,
  a revoked token valid again); the copy before a schema upgrade, under
  its documented name, from a store of schema 1.
- Health: `asphctl health` ok (0), degraded (8) by each check that a test
  can bring about, down (7); GET /healthz 200 ok / 503 degraded.
- Metrics: GET /metrics with the guide's curl, read by a strict reader of
  the text format (version 0.0.4) written from its specification and by
  Debian's prometheus_client parser; the families are the guide's table,
  their values the daemon's; the scrape configuration of docs/fleet.md
  followed.
- Configuration reference: the guide's table is `asphd --list-settings`;
  the complete example holds every setting and passes --check-config.

The daemon with a broker out of reach has its health's times at a
second, so that sink_down and outbox_backlog come at once. The daemons'
store is made bigger (a table of ballast, 24 MiB; 4 MiB under
valgrind) so that the copy takes long enough to be watched."""
import datetime
import grp
import hashlib
import json
import os
import pwd
import re
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import (ASPHCTL, ASPHD, Client, Daemon, expect, finish,  # noqa: E402
                        mock_instrument)

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
VALGRIND = bool(os.environ.get("ASPH_UNDER_VALGRIND"))
with open(os.path.join(ROOT, "docs", "admin.md")) as f:
    GUIDE = f.read()
DAY = "2027-01-31"      # the guide's restore names the backup of that day


def section(text, title, level=2):
    """The text of the section `title` (up to the next heading of its level)."""
    marks = "#" * level
    m = re.search(rf"^{marks} {re.escape(title)}\n(.*?)(?=^{marks} |\Z)", text, re.M | re.S)
    assert m, f"no section {title}"
    return m.group(1)


def blocks(text, lang="sh"):
    """The fenced code blocks of text in lang, each a list of its lines."""
    return [b.strip("\n").split("\n") for b in re.findall(rf"^```{lang}\n(.*?)^```", text,
                                                            re.M | re.S)]


class Guide:
    """Runs the guide's commands for daemon d: what the installed paths are
    here, and systemctl done by the test."""

    def __init__(self, d, backups):
        self.d, self.backups, self.env = d, backups, dict(os.environ)
        self.env["ASPHD_SOCKET"] = d.socket
        self.user = pwd.getpwuid(os.getuid()).pw_name
        self.group = grp.getgrgid(os.getgid()).gr_name
        self.port = None

    def adapt(self, cmd):
        cmd = re.sub(r"^sudo (-u asphd )?", "", cmd)
        cmd = cmd.replace("$(date +%F)", DAY)
        cmd = cmd.replace("/var/lib/asphd", self.d.state).replace("/var/backups/asphd", self.backups)
        cmd = cmd.replace("/etc/asphd/asphd.conf", self.d.config)
        cmd = cmd.replace("-o asphd -g asphd", f"-o {self.user} -g {self.group}")
        cmd = re.sub(r"\basphctl\b", ASPHCTL, cmd, count=1)
        cmd = re.sub(r"^asphd\b", ASPHD, cmd)
        if self.port:
            cmd = cmd.replace("http://localhost:8080", f"http://127.0.0.1:{self.port}")
        return cmd

    def run(self, cmd, want=0):
        """One command of the guide: its output, having checked its exit code."""
        if cmd.startswith("sudo systemctl stop asphd.socket asphd"):
            rc = self.d.stop()
            expect(rc == 0, f"systemctl stop: the daemon stops cleanly ({rc})")
            if rc:
                print(self.d.log_text()[-6000:])
            return ""
        if cmd.startswith("sudo systemctl start asphd.socket asphd"):
            self.d.start()
            return ""
        if cmd.startswith("sudo systemctl reload asphd"):
            self.d.proc.send_signal(signal.SIGHUP)
            return ""
        p = subprocess.run(["bash", "-c", self.adapt(cmd)], capture_output=True, text=True,
                           env=self.env, timeout=600)
        expect(p.returncode == want, f"`{cmd}` exits {want} ({p.returncode}: {p.stderr.strip()[-300:]})")
        return p.stdout

    def run_block(self, lines):
        return [self.run(x) for x in lines]


def add_ballast(path, mib):
    """A table of mib MiB in the store at path, before the daemon's first
    start makes the rest of it: a store of a lab that has measured for a
    while, as far as a copy can tell."""
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE ballast (b BLOB)")
    db.executemany("INSERT INTO ballast VALUES (?)", ((os.urandom(1 << 20),) for _ in range(mib)))
    db.commit()
    db.close()


def sql(path, query):
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return db.execute(query).fetchall()
    finally:
        db.close()


def http(port, path, token=None):
    """(status, headers, body) of GET path on the web listener."""
    req = urllib.request.Request(f"http://127.0.0.1:{port}{path}")
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, r.headers, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.headers, e.read().decode()


def health(d, *args):
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "health", *args], capture_output=True,
                       text=True, timeout=120)
    return p.returncode, p.stdout


# ---------------------------------------------------------- the text format

NAME = r"[a-zA-Z_:][a-zA-Z0-9_:]*"
LABEL = r"[a-zA-Z_][a-zA-Z0-9_]*"
VALUE = r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?Inf|NaN"
LABEL_VALUE = r'"(?:[^"\\\n]|\\[\\"n])*"'
SAMPLE = re.compile(rf"^[ \t]*({NAME})[ \t]*(?:\{{((?:{LABEL}={LABEL_VALUE})(?:,{LABEL}={LABEL_VALUE})*,?)?"
                    rf"\}})?[ \t]+({VALUE})(?:[ \t]+(-?[0-9]+))?[ \t]*$")


def unescape(s):
    return re.sub(r"\\(.)", lambda m: {"\\": "\\", '"': '"', "n": "\n"}[m.group(1)], s)


def strict_parse(text):
    """The exposition read as its specification says (Prometheus,
    "Exposition formats", the text format 0.0.4:
    https://prometheus.io/docs/instrumenting/exposition_formats/), every
    departure an error: lines end with a line feed, the last included;
    tokens apart by blanks or tabs; HELP (escapes \\\\ and \\n only) and
    TYPE at most once per metric and before its samples; a metric's samples
    together; names and labels of their grammar, label values with the
    escapes \\\\, \\" and \\n only; values as Go's ParseFloat reads them; no
    series twice; counters ending in _total. Returns ({family: {type, help,
    samples: [(name, labels, value)]}}, [errors])."""
    errors, families, done, series = [], {}, set(), set()
    current = None
    if not text.endswith("\n"):
        errors.append("the last line does not end with a line feed")
    for n, line in enumerate(text.split("\n")[:-1], 1):
        if line.strip() == "":
            continue
        if line.lstrip().startswith("#"):
            m = re.match(rf"^[ \t]*#[ \t]+(HELP|TYPE)[ \t]+({NAME})(?:[ \t]+(.*?))?[ \t]*$", line)
            if not m:
                if re.match(r"^[ \t]*#[ \t]*(HELP|TYPE)\b", line):
                    errors.append(f"line {n}: a malformed {line.split()[1]}")
                continue
            kind, name, rest = m.groups()
            fam = families.setdefault(name, {"type": None, "help": None, "samples": []})
            if name in done:
                errors.append(f"line {n}: {kind} of {name} after its samples were over")
            if kind == "HELP":
                if fam["help"] is not None:
                    errors.append(f"line {n}: a second HELP of {name}")
                if rest is not None and re.search(r"\\([^\\n]|$)", rest.replace("\\\\", "")):
                    errors.append(f"line {n}: HELP of {name} with a bad escape")
                fam["help"] = re.sub(r"\\(.)", lambda mm: "\n" if mm.group(1) == "n" else "\\",
                                     rest or "")
            else:
                if fam["type"] is not None:
                    errors.append(f"line {n}: a second TYPE of {name}")
                if fam["samples"]:
                    errors.append(f"line {n}: TYPE of {name} after its samples")
                if rest not in ("counter", "gauge", "histogram", "summary", "untyped"):
                    errors.append(f"line {n}: TYPE {rest!r}")
                fam["type"] = rest
            if current and current != name:
                done.add(current)
            current = name
            continue
        m = SAMPLE.match(line)
        if not m:
            errors.append(f"line {n}: not a sample: {line!r}")
            continue
        name, labels_text, value = m.group(1), m.group(2) or "", m.group(3)
        family = name if name in families else None
        if family is None:
            errors.append(f"line {n}: {name} has no HELP or TYPE before it")
            family = name
            families[name] = {"type": "untyped", "help": None, "samples": []}
        if family in done:
            errors.append(f"line {n}: a sample of {name} apart from the others")
        if current and current != family:
            done.add(current)
        current = family
        labels = {k: unescape(v[1:-1]) for k, v in
                  re.findall(rf"({LABEL})=({LABEL_VALUE})", labels_text)}
        if any(k.startswith("__") for k in labels):
            errors.append(f"line {n}: a label starting with __")
        key = (name, tuple(sorted(labels.items())))
        if key in series:
            errors.append(f"line {n}: the series {key} twice")
        series.add(key)
        v = float(value.replace("Inf", "inf").replace("NaN", "nan"))
        families[family]["samples"].append((name, labels, v))
    for name, fam in families.items():
        if fam["type"] == "counter":
            if not name.endswith("_total"):
                errors.append(f"the counter {name} does not end in _total")
            if any(v < 0 for _, _, v in fam["samples"]):
                errors.append(f"the counter {name} has a negative value")
        if fam["type"] is None or fam["help"] is None:
            errors.append(f"{name} lacks its HELP or its TYPE")
    return families, errors


def check_strict_reader():
    """The strict reader refuses what the specification refuses."""
    good = "# HELP a_total A \\\\ b.\n# TYPE a_total counter\na_total{x=\"q\\\"\\n\\\\\"} 1.5e3\n"
    bad = {
        "no final line feed": good[:-1],
        "a bad escape in a label": good.replace('\\"', "\\t"),
        "TYPE after a sample": "# HELP g G.\ng 1\n# TYPE g gauge\n",
        "samples apart": "# HELP g G.\n# TYPE g gauge\ng{a=\"1\"} 1\n# HELP h H.\n# TYPE h gauge\n"
                         "h 1\ng{a=\"2\"} 2\n",
        "a series twice": "# HELP g G.\n# TYPE g gauge\ng 1\ng 2\n",
        "a counter without _total": "# HELP c C.\n# TYPE c counter\nc 1\n",
        "a value Go does not read": "# HELP g G.\n# TYPE g gauge\ng 0x10\n",
        "a label name with a dash": "# HELP g G.\n# TYPE g gauge\ng{a-b=\"1\"} 1\n",
        "a HELP with a bad escape": "# HELP g G\\t.\n# TYPE g gauge\ng 1\n",
        "a sample without its value": "# HELP g G.\n# TYPE g gauge\ng{a=\"1\"}\n",
    }
    spaced = "# HELP g  G.\n\t# TYPE\tg gauge\n g{a=\"1\"}\t 2 1700000000000 \n\n"
    fams, errs = strict_parse(spaced)
    expect(not errs and fams["g"]["samples"] == [("g", {"a": "1"}, 2.0)],
           f"the strict reader takes blanks and tabs between tokens, and a timestamp ({errs})")
    fams, errs = strict_parse(good)
    expect(not errs and fams["a_total"]["samples"] == [("a_total", {"x": "q\"\n\\"}, 1500.0)]
           and fams["a_total"]["help"] == "A \\ b.",
           f"the strict reader reads a valid exposition with escapes ({errs})")
    for what, text in bad.items():
        expect(strict_parse(text)[1], f"the strict reader refuses {what}")


# ------------------------------------------------------------------ parts

def check_reference():
    """The guide's table is the daemon's, and the complete example has
    every setting and passes --check-config."""
    p = subprocess.run([ASPHD, "--list-settings"], capture_output=True, text=True, check=True)
    table = [x.split("\t") for x in p.stdout.strip().split("\n")]
    want = [f"| `{n}` | {t} | {d} | {h} |" for n, t, d, h in table]
    ref = section(GUIDE, "Configuration reference")
    have = [x for x in ref.split("\n") if re.match(r"^\| `", x)]
    missing = [w for w in want if w not in have]
    expect(not missing and have == want, "the guide's reference is asphd --list-settings, row "
           "for row" + ("" if have == want else " (paste these rows):\n" + "\n".join(want)))
    names = [n for n, *_ in table]
    with open(os.path.join(ROOT, "docs", "daemon.md")) as f:
        configure = section(f.read(), "Configure")
    bare = [n for n in names if "." not in n and f"`{n}`" not in configure]
    expect(not bare, f"docs/daemon.md's Configure names every section and setting ({bare})")
    # the other tables of limits: docs/daemon.md's every limit, the
    # protocol's those a client meets, and no other
    limits = sorted(n[7:] for n in names if n.startswith("limits."))
    for doc, every in (("docs/daemon.md", True), ("proto/README.md", False)):
        with open(os.path.join(ROOT, doc)) as f:
            text = section(f.read(), "Limits", 3)
        listed = sorted(re.findall(r"^\| `([a-z_]+)` \|", text, re.M))
        expect(listed == limits if every else listed and set(listed) <= set(limits),
               f"{doc}'s table of limits names {'every limit' if every else 'limits'} of the "
               f"daemon, and no other ({sorted(set(listed) ^ set(limits))})")

    example = os.path.join(ROOT, "systemd", "asphd-complete.conf.example")
    with open(example) as f:
        text = f.read()
    # the example's settings, read as the daemon reads the file
    blanked = re.sub(r'("(?:[^"\\]|\\.)*")|//[^\n]*', lambda m: m.group(1) or "", text)
    cfg = json.loads(blanked)
    have = set(cfg)
    for k in {n.split(".")[0] for n in names if "." in n}:
        have |= {f"{k}.{m}" for m in cfg.get(k, {})}
    expect(set(names) == have, f"the complete example sets every setting "
           f"(missing {sorted(set(names) - have)}, unknown {sorted(have - set(names))})")
    lines = text.split("\n")
    bare = [n for n in names if "." not in n and not any(
        re.match(rf'^\s*"{re.escape(n)}":', x) and
        any(y.strip().startswith("//") for y in lines[max(i - 3, 0):i])
        for i, x in enumerate(lines))]
    expect(not bare, f"each setting of the complete example has a comment above it ({bare})")
    # checked as it is but for the files and the group of this machine
    top = tempfile.mkdtemp(prefix="asphd-conf-")
    try:
        files = {"/etc/asphd/token": "Kq8vT2mXw9LpZr4bNc7YhGd3\n",
                 "/etc/asphd/mqtt-credentials.json": '{"username": "bench1", "password": "pw"}\n',
                 "/etc/asphd/postgres-password": "pw\n",
                 "/etc/asphd/broker-ca.pem": open("/etc/ssl/certs/ca-certificates.crt").read()}
        for path, content in files.items():
            local = os.path.join(top, os.path.basename(path))
            with open(local, "w") as f:
                f.write(content)
            os.chmod(local, 0o600)
            text = text.replace(path, local)
        text = text.replace("/etc/asphd/web", os.path.join(ROOT, "daemon", "web"))
        text = text.replace('"asph-operators"', f'"{grp.getgrgid(os.getgid()).gr_name}"')
        conf = os.path.join(top, "asphd.conf")
        with open(conf, "w") as f:
            f.write(text)
        p = subprocess.run([ASPHD, "--check-config", "--config", conf], capture_output=True,
                           text=True, timeout=60)
        expect(p.returncode == 0 and p.stdout.strip() == f"{conf}: OK, 1 instrument(s)",
               f"asphd --check-config takes the complete example, comments and all "
               f"({p.returncode}: {p.stdout.strip()} {p.stderr.strip()[-400:]})")
        # an error after the comments is still placed on its own line
        bad = text.replace('"max_queue": 10000', '"max_queue": 0')
        line = bad[:bad.index('"max_queue": 0')].count("\n") + 1
        with open(conf, "w") as f:
            f.write(bad)
        p = subprocess.run([ASPHD, "--check-config", "--config", conf], capture_output=True,
                           text=True, timeout=60)
        expect(p.returncode == 3 and f"{conf}:{line}:5: limits.max_queue:" in p.stderr,
               f"an error in the example is named with its line ({line}) and column "
               f"({p.stderr.strip()[-300:]})")
    finally:
        shutil.rmtree(top, ignore_errors=True)


def metrics_check(d, port, token, status):
    """The metrics, read strictly and by prometheus_client: the guide's
    families, the daemon's values."""
    code, headers, text = http(port, "/metrics", token)
    expect(code == 200 and headers["Content-Type"] == "text/plain; version=0.0.4; charset=utf-8",
           f"GET /metrics with a viewer's bearer token: 200, the text format 0.0.4 ({code})")
    families, errors = strict_parse(text)
    expect(not errors, f"the exposition is valid to the letter of the format ({errors[:5]})")
    from prometheus_client.parser import text_string_to_metric_families
    parsed = {f.name: f for f in text_string_to_metric_families(text)}
    n_samples = sum(len(f.samples) for f in parsed.values())
    expect(n_samples == sum(len(f["samples"]) for f in families.values()),
           f"prometheus_client reads every sample ({n_samples})")
    # the guide's table: every family, its type and labels
    table = re.findall(r"^\| `([a-z_]+)` \| (counter|gauge) \|([^|]*)\|",
                       section(GUIDE, "Metrics"), re.M)
    documented = {n: (t, sorted(re.findall(r"`([a-z_]+)`", labels))) for n, t, labels in table}
    served = {}
    for name, fam in families.items():
        labels = sorted({k for _, ls, _ in fam["samples"] for k in ls})
        served[name] = (fam["type"], labels)
    sinkless = {n for n in documented if n.startswith(("asphd_outbox", "asphd_sink"))}
    expect({n: v for n, v in served.items()} ==
           {n: v for n, v in documented.items() if n not in sinkless or n in served},
           f"the families served are the guide's, with its types and labels "
           f"({sorted(set(served) ^ set(documented))})")

    def value(name, **labels):
        for n, ls, v in families.get(name, {"samples": []})["samples"]:
            if n == name and all(ls.get(k) == w for k, w in labels.items()):
                return v
        return None

    for state, n in status["jobs"].items():
        expect(value("asphd_jobs", state=state) == n, f"asphd_jobs{{state={state}}} is "
               f"daemon.status's {n}")
    for ins in status["instruments"]:
        expect(value("asphd_instrument_state", instrument=ins["name"], state=ins["state"]) == 1
               and sum(v for n, ls, v in families["asphd_instrument_state"]["samples"]
                       if ls["instrument"] == ins["name"]) == 1,
               f"{ins['name']}: asphd_instrument_state is 1 for {ins['state']} only")
    pid = d.proc.pid
    fds = len(os.listdir(f"/proc/{pid}/fd"))
    expect(abs(value("process_open_fds") - fds) <= 2,
           f"process_open_fds {value('process_open_fds')} is the daemon's ({fds} in /proc)")
    with open(f"/proc/{pid}/status") as f:
        rss = int(re.search(r"VmRSS:\s+(\d+) kB", f.read()).group(1)) * 1024
    expect(0.5 * rss < value("process_resident_memory_bytes") < 2 * rss,
           f"process_resident_memory_bytes {value('process_resident_memory_bytes')} is near "
           f"the daemon's VmRSS {rss}")
    expect(value("process_start_time_seconds") <= time.time() and
           value("process_max_fds") >= fds, "the start time and the descriptor limit")
    return value, documented


def part_backup_restore(d, c, backups, guide):
    """Backup while a job runs, restore, and what the guide says follows."""
    text = section(GUIDE, "Backup and restore")
    store = os.path.join(d.state, "jobs.sqlite")
    c.call("events.subscribe", {"events": ["job"]})
    first = c.call("job.submit", {"lens": "strong", "instrument": "bench",
                                  "plan": {"method": "fermat", "points": 600 if VALGRIND else 1500}})["id"]
    kept = c.call("token.create", {"name": "kept", "role": "viewer"})["token"]
    deadline = time.time() + 300
    while c.call("job.get", {"id": first})["progress"]["done"] < 50 and time.time() < deadline:
        time.sleep(0.05)
    # a second client asks for the status all through the copy
    latencies, stop = [], threading.Event()

    def ask():
        other = Client(d.socket)
        while not stop.is_set():
            t = time.monotonic()
            other.call("daemon.status")
            latencies.append(time.monotonic() - t)
            time.sleep(0.01)
        other.close()

    asker = threading.Thread(target=ask)
    asker.start()
    done_before = c.call("job.get", {"id": first})["progress"]["done"]
    backup_cmds = blocks(section(text, "The job store", 3))
    out = guide.run_block(backup_cmds[0])[1]
    done_after = c.call("job.get", {"id": first})["progress"]["done"]
    stop.set()
    asker.join()
    copy = os.path.join(backups, f"jobs-{DAY}.sqlite")
    m = re.match(rf"^{re.escape(copy)}: the job store as of \S+Z, (\d+) bytes, sha256 ([0-9a-f]{{64}})$",
                 out.strip())
    expect(m is not None, f"asphctl backup prints the file, the moment, the size and the SHA-256 ({out!r})")
    with open(copy, "rb") as f:
        data = f.read()
    expect(m and int(m.group(1)) == len(data) and m.group(2) == hashlib.sha256(data).hexdigest(),
           "the size and SHA-256 printed are the file's")
    expect(os.stat(copy).st_mode & 0o777 == 0o600, "the copy is written with mode 0600")
    # (valgrind runs one thread at a time: the copy's holds the loop's off
    # while it has the processor)
    bound = 10.0 if VALGRIND else 1.0
    expect(latencies and max(latencies) < bound,
           f"daemon.status answered all through the copy: {len(latencies)} calls, the "
           f"slowest {max(latencies or [0]) * 1000:.0f} ms (at most {bound:.0f} s)")
    expect(done_after > done_before, f"the job measured on during the copy ({done_before} -> "
           f"{done_after} points)")
    checks = guide.run_block(backup_cmds[1])
    expect(checks[0].strip() == "ok", f"PRAGMA integrity_check of the copy says ok ({checks[0]!r})")
    expect(int(checks[1]) == 1, f"the copy holds the job ({checks[1]!r})")
    expect(sql(copy, f"SELECT state FROM jobs WHERE id = {first}") == [(1,)],
           "the copy has the job running, as it was at the moment of the copy")
    expect(not os.path.exists(copy + "-wal"), "the copy needs no -wal file")
    expect(not [x for x in os.listdir(os.path.join(d.state, "backup")) if x.startswith("copy-")],
           "the daemon's own copy is gone once asphctl is done")
    # the lines the guide's Logs quote
    expect(re.search(r"^asphd: backup: the job store copied for root into copy-\S+\.sqlite: "
                     r"\d+ bytes in [\d.]+ s, sha256 [0-9a-f]{64}$", d.log_text(), re.M) and
           re.search(rf"^asphd: job {first}: ", d.log_text(), re.M),
           "the log has the backup's line and the job's lines as the guide's Logs show them")
    c.wait_state(first, ["completed"], timeout=600)
    guide.run_block(blocks(section(text, "Scans and results", 3))[0])
    expect(os.path.getsize(os.path.join(backups, f"folders-{DAY}.tar.gz")) > 0,
           "the folders' archive is written")

    # after the backup: a job, a token made, the kept token revoked
    later = c.call("job.submit", {"lens": "strong", "instrument": "bench",
                                  "plan": {"method": "fermat", "points": 100}})["id"]
    c.wait_state(later, ["completed"], timeout=300)
    c.call("token.create", {"name": "newer", "role": "viewer"})
    c.call("token.revoke", {"name": "kept"})
    c.close()

    restore = blocks(section(text, "Restore", 3))[0]
    outs = guide.run_block(restore)
    expect(outs[1].strip() == "ok", "the restore's integrity check says ok")
    listed = outs[-1]
    expect(re.search(rf"^\s*{first}\b", listed, re.M) and not re.search(rf"^\s*{later}\b",
                                                                       listed, re.M),
           f"asphctl list after the restore: the job of the copy, not the later one\n{listed}")
    c = Client(d.socket)
    j = c.call("job.get", {"id": first})
    expect(j["state"] == "interrupted" and j["resumable"],
           f"the job running at the copy comes back interrupted and resumable ({j['state']})")
    c.call("events.subscribe", {"events": ["job"]})
    c.call("job.resume", {"id": first})
    expect(c.wait_state(first, ["completed", "failed"], timeout=600) == "completed",
           "asphctl resume completes it from its recorded scan")
    tokens = {t["name"]: t["state"] for t in c.call("token.list")["tokens"]}
    expect(tokens == {"kept": "active"}, f"the tokens are the copy's: the later one gone, the "
           f"one revoked since active again ({tokens})")
    expect(os.stat(store).st_mode & 0o777 == 0o640, "the store is back with mode 0640")
    # the later job's folder, which the restored store does not know, is
    # not taken by the next job
    with open(os.path.join(d.state, "jobs", str(later), "result.json"), "rb") as f:
        kept_result = f.read()
    nxt = c.call("job.submit", {"lens": "strong", "instrument": "bench",
                                "plan": {"method": "fermat", "points": 100}})["id"]
    c.wait_state(nxt, ["completed"], timeout=300)
    with open(os.path.join(d.state, "jobs", str(later), "result.json"), "rb") as f:
        same = f.read() == kept_result
    expect(nxt > later and same and "new jobs start after them" in d.log_text(),
           f"the next job ({nxt}) starts after the folders the restored store does not know "
           f"(up to {later}), which stay as they were")
    c.close()
    return kept


def part_upgrade_backup():
    """A store of schema 1: copied as it was, under the documented name,
    and logged, before the daemon upgrades it."""
    d = Daemon(instruments=[mock_instrument()])
    try:
        os.makedirs(d.state, mode=0o750)
        db = sqlite3.connect(os.path.join(d.state, "jobs.sqlite"))
        db.executescript("""
            CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
            CREATE TABLE jobs (id INTEGER PRIMARY KEY AUTOINCREMENT, state INTEGER NOT NULL,
              priority INTEGER NOT NULL, seq INTEGER NOT NULL, label TEXT,
              instrument TEXT NOT NULL, uid INTEGER NOT NULL, user TEXT, spec TEXT NOT NULL,
              submitted_ns INTEGER NOT NULL, started_ns INTEGER NOT NULL,
              finished_ns INTEGER NOT NULL, points_done INTEGER NOT NULL,
              points_total INTEGER NOT NULL, reason TEXT, result TEXT, scan_path TEXT,
              resume INTEGER NOT NULL, attempts INTEGER NOT NULL);
            CREATE TABLE history (job INTEGER NOT NULL REFERENCES jobs(id),
              t_ns INTEGER NOT NULL, state INTEGER NOT NULL, reason TEXT,
              actor_uid INTEGER NOT NULL);
            INSERT INTO meta VALUES ('schema', '1');
            INSERT INTO jobs VALUES (1, 5, 0, 1, 'from 1', 'mock', 0, 'root',
              '{"lens":"strong","plan":{"method":"ci","h":0.05}}', 1700000000000000000,
              0, 1700000001000000000, 0, 1653, NULL, NULL, NULL, 0, 0);
            INSERT INTO history VALUES (1, 1700000000000000000, 0, NULL, 0);
            """)
        db.close()
        d.start()
        backups = os.listdir(os.path.join(d.state, "backup"))
        expect(len(backups) == 1 and re.fullmatch(r"jobs-schema1-\d{8}T\d{6}Z\.sqlite", backups[0]),
               f"the copy before the upgrade is backup/jobs-schema1-YYYYmmddTHHMMSSZ.sqlite ({backups})")
        copy = os.path.join(d.state, "backup", backups[0]) if backups else ""
        expect(backups and sql(copy, "SELECT value FROM meta WHERE key = 'schema'") == [("1",)]
               and sql(copy, "SELECT label FROM jobs") == [("from 1",)],
               "the copy is the store of schema 1 as it was")
        line = re.search(r"^asphd: the job store (\S+) has schema 1: backed up to (\S+) before its "
                         r"upgrade to schema (\d+)$", d.log_text(), re.M)
        expect(line and line.group(2) == copy, f"the log names the copy as the guide shows it")
        c = Client(d.socket)
        expect(c.call("job.get", {"id": 1})["label"] == "from 1", "the upgraded store has the job")
        c.close()
    finally:
        d.cleanup()


def part_health_metrics(d, guide, token):
    """asphctl health and /healthz through the checks; the metrics."""
    text = section(GUIDE, "Health")
    c = Client(d.socket)
    c.call("events.subscribe", {"events": ["job"]})
    out = guide.run_block(blocks(text)[0])[0]
    expect(out == "ok\n", f"asphctl health says ok ({out!r})")
    port = guide.port
    expect(guide.run_block(blocks(text)[1])[0] == "ok\n", "curl /healthz says ok")
    # queue_stopped
    c.call("queue.stop")
    job = c.call("job.submit", {"lens": "strong", "instrument": "bench",
                                "plan": {"method": "fermat", "points": 100}})["id"]
    rc, out = health(d)
    expect(rc == 8 and out.startswith("degraded\n  queue_stopped: the queue is stopped with 1 "),
           f"a stopped queue with a job waiting: degraded, exit 8, the reason printed ({rc}: {out!r})")
    code, _, body = http(port, "/healthz")
    expect(code == 503 and body == "degraded\n", f"GET /healthz: 503 degraded ({code} {body!r})")
    c.call("queue.start")
    c.wait_state(job, ["completed"], timeout=300)
    # store_reserve
    os.unlink(os.path.join(d.state, "jobs.sqlite.reserve"))
    rc, out = health(d, "--json")
    reasons = json.loads(out)["reasons"] if rc == 8 else []
    expect(rc == 8 and [r["check"] for r in reasons] == ["store_reserve"],
           f"the store's reserve gone: degraded by store_reserve ({rc}: {out.strip()})")
    job = c.call("job.submit", {"lens": "strong", "instrument": "bench",
                                "plan": {"method": "fermat", "points": 100}})["id"]
    c.wait_state(job, ["completed"], timeout=300)
    expect(health(d)[0] == 0, "a job's start makes the reserve again: ok")
    # instrument_fault, and the error it counts
    bad = c.call("job.submit", {"lens": "strong", "instrument": "flaky",
                                "plan": {"method": "fermat", "points": 300}})["id"]
    c.wait_state(bad, ["failed"], timeout=300)
    rc, out = health(d)
    expect(rc == 8 and "\n  instrument_fault: instrument flaky: its last job stopped on a fault: "
           in out, f"a driver fault: degraded by instrument_fault ({out!r})")
    # the metrics, through the guide's commands
    metrics_text = section(GUIDE, "Metrics")
    cmds = blocks(metrics_text)[0]
    created = guide.run(cmds[0])
    secret = re.search(r"asph_[A-Za-z0-9_-]{43}", created).group(0)
    guide.env["TOKEN"] = secret
    scraped = guide.run(cmds[1])
    expect("asphd_jobs{state=\"completed\"}" in scraped, "the guide's curl reads the metrics")
    status = c.call("daemon.status")
    value, documented = metrics_check(d, port, secret, status)
    # since the restart: three jobs of 100 points; the resumed one found
    # its scan complete and measured nothing
    measured = value("asphd_points_measured_total", instrument="bench")
    expect(measured == 300, f"asphd_points_measured_total counts the points measured since "
           f"the start ({measured}, 300 wanted)")
    expect(value("asphd_errors_total", kind="job_failed") == 1 and
           value("asphd_health_degraded", check="instrument_fault") == 1 and
           value("asphd_health_degraded", check="queue_stopped") == 0,
           "the failed job is counted, and the health's checks are told")
    code, headers, _ = http(port, "/metrics")
    expect(code == 401 and headers["WWW-Authenticate"] == 'Bearer realm="asphd"',
           f"/metrics without a token: 401 with the Bearer challenge ({code})")
    code, headers, _ = http(port, "/metrics", "asph_" + "A" * 43)
    expect(code == 401 and "invalid_token" in headers["WWW-Authenticate"],
           f"/metrics with a wrong token: 401 invalid_token ({code})")
    expect(http(port, "/metrics", token)[0] == 200, "a viewer token made earlier reads them too")

    # the scrape configuration of docs/fleet.md, followed
    import yaml
    with open(os.path.join(ROOT, "docs", "fleet.md")) as f:
        fleet = f.read()
    scrape = yaml.safe_load("\n".join(blocks(fleet, "yaml")[0]))["scrape_configs"][0]
    auth = scrape["authorization"]
    tokfile = os.path.join(d.top, "prometheus-token")
    with open(tokfile, "w") as f:
        f.write(secret + "\n")
    expect(auth.get("type", "Bearer") == "Bearer" and scrape.get("metrics_path") == "/metrics"
           and scrape.get("scheme", "http") == "http" and auth["credentials_file"].startswith("/"),
           "docs/fleet.md scrapes /metrics over HTTP with a bearer token from a file")
    with open(tokfile) as f:    # Prometheus reads the file and trims it
        cred = f.read().strip()
    code, _, body = http(port, scrape["metrics_path"], cred)
    expect(code == 200 and "# TYPE asphd_points_measured_total counter" in body,
           "a scrape as docs/fleet.md configures it reads the metrics")
    queries = [x for b in blocks(fleet, "promql") for x in b if x and not x.startswith("#")]
    queries += [r["expr"] for b in blocks(fleet, "yaml")[1:]
                for g in yaml.safe_load("\n".join(b))["groups"] for r in g["rules"]]
    expect(queries, "docs/fleet.md has Grafana queries and alerts on the metrics")
    for q in queries:
        used = set(re.findall(r"\b((?:asphd|process)_[a-z_]+)", q))
        expect(used and used <= set(documented), f"the query {q!r} uses metrics the daemon "
               f"serves ({sorted(used - set(documented))} not)")

    # disk_low: the reload of the guide's Configuration reference
    with open(d.config) as f:
        cfg = json.load(f)
    cfg.setdefault("limits", {})["min_free_disk_mb"] = 1048576
    with open(d.config, "w") as f:
        json.dump(cfg, f)
    for cmd in blocks(section(GUIDE, "Configuration reference"))[0]:
        guide.run(cmd)
    deadline = time.time() + 60
    while time.time() < deadline and not any(
            r["check"] == "disk_low" for r in c.call("daemon.health")["reasons"]):
        time.sleep(0.1)
    rc, out = health(d)
    expect(rc == 8 and "\n  disk_low: the state directory " in out,
           f"min_free_disk_mb over the free room, reloaded: degraded by disk_low ({out!r})")
    c.close()


def start_sinks_daemon():
    """A daemon whose MQTT broker is out of reach, its health's times
    (health.sink_down_s, health.outbox_age_s) set to a second: the broker
    counts as down, and the messages of a job as waiting too long, a
    second after."""
    s = Daemon(instruments=[mock_instrument()],
               extra={"mqtt": {"url": f"mqtt://127.0.0.1:{free_tcp_port()}"},
                      "health": {"sink_down_s": 1, "outbox_age_s": 1}})
    s.start()
    c = Client(s.socket)
    # job states for the outbox, without a measurement
    c.call("queue.stop")
    job = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 100}})["id"]
    c.call("job.cancel", {"id": job})
    c.close()
    return s


def check_sinks(s):
    """What the daemon with its broker out of reach says, more than a
    second on."""
    c, deadline = Client(s.socket), time.time() + 60
    while time.time() < deadline and sorted(
            r["check"] for r in c.call("daemon.health")["reasons"]) != ["outbox_backlog", "sink_down"]:
        time.sleep(0.2)
    c.close()
    rc, out = health(s, "--json")
    checks = sorted(r["check"] for r in json.loads(out)["reasons"]) if rc == 8 else []
    expect(checks == ["outbox_backlog", "sink_down"] and rc == 8,
           f"a broker out of reach past health.sink_down_s, a message waiting past "
           f"health.outbox_age_s: degraded by sink_down and outbox_backlog ({rc}: {out.strip()})")
    expect('"detail": "mqtt: out of reach since ' in out and '"detail": "mqtt: ' in out,
           "each names the sink")


def last_web_port(d):
    """The port of d's web listener at its last start (its log goes on
    from start to start)."""
    deadline = time.time() + 60
    while time.time() < deadline:
        ports = re.findall(r"web page at http://127\.0\.0\.1:(\d+)/", d.log_text())
        if ports and len(ports) == d.log_text().count("asphd: listening on"):
            return int(ports[-1])
        time.sleep(0.05)
    raise RuntimeError("no web page address in the log")


def free_tcp_port():
    with socket.socket() as t:
        t.bind(("127.0.0.1", 0))
        return t.getsockname()[1]


def part_down():
    """down: nothing at the socket, or a daemon that does not answer."""
    top = tempfile.mkdtemp(prefix="asphd-down-")
    try:
        path = os.path.join(top, "asphd.sock")
        p = subprocess.run([ASPHCTL, "--socket", path, "health"], capture_output=True, text=True,
                           timeout=60)
        expect(p.returncode == 7 and p.stdout.startswith("down: cannot reach asphd: "),
               f"no daemon: down, exit 7 ({p.returncode}: {p.stdout.strip()})")
        # a socket that accepts and never answers: a hung daemon
        mute = socket.socket(socket.AF_UNIX)
        mute.bind(path)
        mute.listen(1)
        t = time.monotonic()
        p = subprocess.run([ASPHCTL, "--socket", path, "health", "--timeout", "1", "--json"],
                           capture_output=True, text=True, timeout=60)
        took = time.monotonic() - t
        mute.close()
        out = json.loads(p.stdout) if p.returncode == 7 else {}
        expect(p.returncode == 7 and out.get("status") == "down" and
               "did not answer" in out.get("detail", "") and took < 30,
               f"a daemon that does not answer within --timeout 1: down, exit 7 "
               f"({p.returncode}: {p.stdout.strip()}, {took:.1f} s)")
    finally:
        shutil.rmtree(top, ignore_errors=True)


T0 = time.monotonic()


def mark(what):
    print(f"# {time.monotonic() - T0:.1f} s: {what}")


check_strict_reader()
part_down()
if VALGRIND:
    # (their C code runs under valgrind in test-settings and test-store;
    # here it would cost three starts of asphd under valgrind)
    print("# under valgrind: the configuration reference and the upgrade's backup left out")
else:
    check_reference()
    part_upgrade_backup()
mark("reference, down, upgrade")
sinks = start_sinks_daemon()
mark("sinks daemon")
d = Daemon(instruments=[mock_instrument("bench", time_factor=0.05),
                        mock_instrument("flaky", fail_after=40)],
           extra={"http_listen": "127.0.0.1:0"})
backups = tempfile.mkdtemp(prefix="asphd-backups-")
try:
    os.makedirs(d.state, mode=0o750)
    add_ballast(os.path.join(d.state, "jobs.sqlite"), 4 if VALGRIND else 24)
    d.start()
    guide = Guide(d, os.path.join(backups, "asphd"))
    guide.port = last_web_port(d)
    c = Client(d.socket)
    mark("ballast")
    kept = part_backup_restore(d, c, guide.backups, guide)
    mark("backup and restore")
    guide.port = last_web_port(d)   # (a new one since the restart)
    part_health_metrics(d, guide, kept)
    mark("health and metrics")
    check_sinks(sinks)
except Exception:
    print(d.log_text()[-4000:])
    raise
finally:
    d.cleanup()
    sinks.cleanup()
    shutil.rmtree(backups, ignore_errors=True)
finish()
