#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Feeds every malformed request of protocol_cases.py to one running asphd
(mock instruments) and checks, for each input:

- the documented answer: the JSON-RPC error code of proto/README.md with
  its message from the README's table, a detail that names what is wrong
  (the parameter, the member, the limit, or the column of a parse error,
  checked against where the fault is), the request's id when it could be
  read (else null); no answer where none is due (notifications), and no
  extra answer (a sentinel request follows every input);
- no crash and no hang: the daemon's process is alive, every answer comes
  within the timeout, no sanitizer or valgrind report appears;
- the daemon still answers: daemon.status on a separate connection after
  every input (and throughout the 100 MB lines), from the same process;
- other clients' jobs are unaffected: another client's job, submitted
  before the corpus, measures during it (one after another, as long as the
  corpus runs) and each completes with a fit identical to a reference run
  of the same job before the corpus.

  test-badinput-protocol.py          run the corpus
  test-badinput-protocol.py --list   count the cases per category

Exit 0 when every input was answered as documented, 1 otherwise, 77
without asphd.
"""
import grp
import json
import os
import re
import socket
import sys
import threading
import time
from collections import Counter

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
import protocol_cases as pc  # noqa: E402
from daemontest import Client, Daemon, mock_instrument  # noqa: E402

SLOW = bool(os.environ.get("ASPH_UNDER_VALGRIND"))
TIMEOUT = 300 if SLOW else 60          # for one answer
# limits.request_timeout_ms: the stalled input. Under valgrind, beside the
# other valgrind tests on two cores, reading a 1 MiB line can itself take
# longer than 5 s, and the line would be timed out as incomplete.
REQUEST_TIMEOUT_MS = 30000 if SLOW else 5000
SANITIZER = re.compile(r"Sanitizer|runtime error:|^==\d+==", re.M)

# The other client's job: a misaligned part with form error and seeded
# noise, so that its fit is a sharp fingerprint of the measured points. The
# mock's noise depends on the seed and the point only, so the reference on
# the fast instrument measures the same points.
PART = {"shift_x": 0.0137, "shift_y": -0.0071, "tilt_x": 37, "form": "5:23;8:-11",
        "noise": 2.7, "seed": 9091}
SPEC = {"lens": "strong", "plan": {"method": "fermat", "points": 300}}


def documented_messages():
    """code -> message, from the error table of proto/README.md."""
    root = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(HERE, "..", ".."))
    with open(os.path.join(root, "proto", "README.md")) as f:
        table = f.read().split("## Error codes", 1)[1].split("\n## ", 1)[0]
    return {int(m.group(1)): m.group(2).strip()
            for m in re.finditer(r"^\| (-?\d+) \| ([^|]+) \|", table, re.M)}


class Conn:
    """A raw connection: bytes out, one JSON text per line in. Events
    (notifications from the daemon) are counted and skipped."""

    def __init__(self, path):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(TIMEOUT)
        self.sock.connect(path)
        self.buf = b""
        self.events = 0

    def send(self, parts):
        for p in parts:
            self.sock.sendall(p)

    def _line(self):
        while b"\n" not in self.buf:
            chunk = self.sock.recv(1 << 20)
            if not chunk:
                raise EOFError("the daemon closed the connection")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return line

    def read(self):
        while True:
            m = json.loads(self._line())
            if isinstance(m, dict) and "method" in m and "id" not in m:
                self.events += 1
                continue
            return m

    def closed(self):
        """True when the daemon closes the connection with nothing more."""
        try:
            while True:
                chunk = self.sock.recv(65536)
                if not chunk:
                    return not self.buf.strip()
                self.buf += chunk
        except OSError:
            return False

    def close(self):
        self.sock.close()


def same_id(got, want):
    if want is None or got is None:
        return got is None and want is None
    if isinstance(want, str) or isinstance(got, str):
        return got == want
    return not isinstance(got, bool) and isinstance(got, (int, float)) and got == want


def judge(msg, want, messages):
    """None if msg is the answer want (Err or OK), else why not."""
    if want == pc.OK:
        if isinstance(msg, dict) and msg.get("jsonrpc") == "2.0" and "result" in msg:
            return None
        return "a result expected, got %s" % json.dumps(msg)[:300]
    if not isinstance(msg, dict) or set(msg) != {"jsonrpc", "id", "error"} or msg["jsonrpc"] != "2.0":
        return "not an error response: %s" % json.dumps(msg)[:300]
    err = msg["error"]
    if not isinstance(err, dict) or err.get("code") != want.code:
        return "error %s, documented %d: %s" % (err.get("code"), want.code, json.dumps(err)[:300])
    if err.get("message") != messages.get(want.code):
        return "message %r, documented %r" % (err.get("message"), messages.get(want.code))
    detail = (err.get("data") or {}).get("detail") if isinstance(err.get("data"), dict) else None
    if not isinstance(detail, str) or not re.search(want.detail, detail):
        return "the detail %r does not say /%s/" % (detail, want.detail)
    if not same_id(msg["id"], want.id):
        return "id %r, the request's was %r" % (msg["id"], want.id)
    if want.column:
        m = re.match(r"column (\d+)", detail)
        col = int(m.group(1)) if m else -1
        if not want.column[0] <= col <= want.column[1]:
            return "the detail names column %d, the fault is at %d..%d: %r" % (
                col, want.column[0], want.column[1], detail)
    return None


def judge_answer(msg, want, messages):
    if not isinstance(want, list):
        return judge(msg, want, messages)
    if not isinstance(msg, list) or len(msg) != len(want):
        return "a batch of %d answers expected, got %s" % (len(want), json.dumps(msg)[:300])
    left = list(want)
    for m in msg:
        for i, w in enumerate(left):
            if judge(m, w, messages) is None:
                del left[i]
                break
        else:
            return "batch answer not expected: %s (first refusal: %s)" % (
                json.dumps(m)[:200], judge(m, left[0], messages) if left else "")
    return None


class Victim:
    """Another client with a job on the instrument 'bench' while the
    corpus runs; each of its jobs must end as the reference did."""

    def __init__(self, d):
        self.c = Client(d.socket, timeout=TIMEOUT)
        self.jobs, self.reference, self.failures = [], None, []
        self.measuring = 0
        self.done = -1

    def run_reference(self):
        t = time.time()
        j = self.c.call("job.submit", dict(SPEC, instrument="ref"))["id"]
        while self.c.call("job.get", {"id": j})["state"] not in ("completed", "failed", "cancelled"):
            time.sleep(0.02)
        self.reference = self.c.call("job.result", {"id": j})["summary"]
        return j, time.time() - t

    def start(self):
        self.jobs.append(self.c.call("job.submit", dict(SPEC, instrument="bench"))["id"])
        self.done = -1

    def check_completed(self, job):
        j = self.c.call("job.get", {"id": job, "history": True})
        states = [h["state"] for h in j["history"]]
        if j["state"] != "completed" or states != ["queued", "running", "completed"] or j["attempts"] != 1:
            self.failures.append("job %d: %s after %s, %d attempt(s), %s" % (
                job, j["state"], states, j["attempts"], j["reason"]))
            return
        summary = self.c.call("job.result", {"id": job})["summary"]
        if summary != self.reference:
            self.failures.append("job %d: the fit differs from the reference:\n%s\n%s" % (
                job, json.dumps(summary)[:800], json.dumps(self.reference)[:800]))

    def tick(self, status):
        """After an input: the job still measures (its progress grows), or
        it has completed as the reference did and the next one starts."""
        job = self.jobs[-1]
        j = self.c.call("job.get", {"id": job})
        if j["state"] in ("queued", "running"):
            if j["progress"]["done"] < self.done:
                self.failures.append("job %d: progress went back" % job)
            self.done = j["progress"]["done"]
            bench = [i for i in status["instruments"] if i["name"] == "bench"]
            self.measuring += bool(bench and bench[0]["job"] == job and bench[0]["state"] == "measuring")
            return
        self.check_completed(job)
        self.start()

    def finish(self):
        job = self.jobs[-1]
        deadline = time.time() + 60 * (10 if SLOW else 1)
        while self.c.call("job.get", {"id": job})["state"] in ("queued", "running"):
            if time.time() > deadline:
                self.failures.append("job %d did not complete" % job)
                return
            time.sleep(0.05)
        self.check_completed(job)


class Run:
    def __init__(self, d, messages):
        self.d, self.messages = d, messages
        self.status = Client(d.socket, timeout=TIMEOUT)
        self.shared = Conn(d.socket)
        self.victim = Victim(d)
        self.log_seen = 0
        self.valgrind_log = None
        sc = sys.modules.get("sitecustomize")
        if sc is not None and getattr(sc, "_LOGDIR", None):
            self.valgrind_log = os.path.join(sc._LOGDIR, "%d.log" % d.proc.pid)
        self.sentinel = 0
        self.status_calls = 0

    def alive(self, after_input=True):
        """None if the daemon runs, answers daemon.status on another
        connection (same process) and reported nothing, else why not;
        after an input, the other client's job is looked at too."""
        if self.d.proc.poll() is not None:
            return "the daemon exited with %s" % self.d.proc.returncode
        try:
            st = self.status.call("daemon.status")
        except Exception as e:  # noqa: BLE001 - any failure to answer is the finding
            return "daemon.status on another connection failed: %r" % e
        self.status_calls += 1
        if st["pid"] != self.d.proc.pid:
            return "daemon.status answered by pid %s, not %d" % (st["pid"], self.d.proc.pid)
        text = self.d.log_text()
        new, self.log_seen = text[self.log_seen:], len(text)
        if SANITIZER.search(new):
            return "sanitizer report:\n" + new[-3000:]
        report = sys.modules["sitecustomize"].report_text(self.valgrind_log) \
            if self.valgrind_log else ""
        if report:
            return "valgrind report:\n" + report[-3000:]
        if after_input:
            self.victim.tick(st)
        return None

    def expect_answers(self, conn, case):
        for i, want in enumerate(case.answers):
            try:
                msg = conn.read()
            except (OSError, EOFError, ValueError) as e:
                return "answer %d of %d: %r" % (i + 1, len(case.answers), e)
            why = judge_answer(msg, want, self.messages)
            if why:
                return "answer %d of %d: %s" % (i + 1, len(case.answers), why)
        return None

    def shared_case(self, case):
        parts = case.send if isinstance(case.send, list) else [case.send]
        self.shared.send(parts)
        why = self.expect_answers(self.shared, case)
        if why:
            return why
        # Nothing more may come: the next answer is the sentinel's.
        self.sentinel += 1
        sid = "sentinel-%d" % self.sentinel
        self.shared.send([pc.line(pc.request("version", rid=sid))])
        try:
            m = self.shared.read()
        except (OSError, EOFError, ValueError) as e:
            return "no answer to the request after it: %r" % e
        if not (isinstance(m, dict) and m.get("id") == sid and "result" in m):
            return "an answer more than documented: %s" % json.dumps(m)[:300]
        return None

    def eof_case(self, case):
        c = Conn(self.d.socket)
        try:
            c.send([case.send])
            c.sock.shutdown(socket.SHUT_WR)
            why = self.expect_answers(c, case)
            if not why and not c.closed():
                why = "the daemon did not close the connection after its answers"
            return why
        finally:
            c.close()

    def flood_case(self, case):
        """Streams the chunks from a thread; meanwhile daemon.status must
        be answered on another connection."""
        c = Conn(self.d.socket)
        sent, error = [0], []

        def pump():
            try:
                for chunk in case.send():
                    c.sock.sendall(chunk)
                    sent[0] += len(chunk)
                c.sock.shutdown(socket.SHUT_WR)
            except OSError as e:
                error.append(e)

        t0 = time.time()
        th = threading.Thread(target=pump)
        th.start()
        polls, worst = 0, 0.0
        while th.is_alive():
            t = time.time()
            why = self.alive(after_input=False)
            if why:
                th.join()
                c.close()
                return "while the line was sent: " + why
            polls += 1
            worst = max(worst, time.time() - t)
            th.join(0.1)
        try:
            if error:
                return "sending failed after %d bytes: %r" % (sent[0], error[0])
            why = self.expect_answers(c, case)
            if not why and not c.closed():
                why = "the daemon did not close the connection after its answers"
            print("  %s: %d MB in %.2f s, daemon.status answered %d times meanwhile (slowest %.3f s)" % (
                case.name, sent[0] >> 20, time.time() - t0, polls, worst))
            return why
        finally:
            c.close()

    def reopen_shared(self):
        self.shared.close()
        self.shared = Conn(self.d.socket)


def main():
    cases = pc.all_cases()
    per_category = Counter(c.category for c in cases)
    if sys.argv[1:2] == ["--list"]:
        for cat, n in per_category.items():
            print("%-36s %4d" % (cat, n))
        print("%-36s %4d" % ("total", len(cases)))
        return 0
    asphd = os.environ.get("ASPHD_BIN")
    if not asphd or not os.access(asphd, os.X_OK):
        print("ASPHD_BIN must name the asphd binary")
        return 77
    messages = documented_messages()
    extra = {"limits": {"request_timeout_ms": REQUEST_TIMEOUT_MS}}
    if os.geteuid() != 0:
        extra["operator_group"] = grp.getgrgid(os.getegid()).gr_name
    d = Daemon(instruments=[mock_instrument("bench", time_factor=0.15, **PART),
                            mock_instrument("ref", time_factor=0, **PART)], extra=extra)
    failed = Counter()
    t_start = time.time()
    try:
        d.start()
        run = Run(d, messages)
        ref, t_ref = run.victim.run_reference()
        print("reference run: job %d, %.1f s" % (ref, t_ref))
        stall = [c for c in cases if c.conn == "stall"]
        stalls = []
        for c in stall:
            s = Conn(d.socket)
            s.send([c.send])
            stalls.append((c, s))
        run.victim.start()
        t0 = time.time()
        for i, case in enumerate(cases):
            if case.conn == "stall":
                continue
            if case.conn == "shared":
                why = run.shared_case(case)
            elif case.conn == "eof":
                why = run.eof_case(case)
            else:
                why = run.flood_case(case)
            if why and case.conn == "shared":
                run.reopen_shared()
            after = run.alive()
            if after:
                why = (why + "; " if why else "") + after
            if why:
                failed[case.category] += 1
                print("FAIL %s/%s: %s" % (case.category, case.name, why.rstrip()))
                sys.stdout.flush()
                if run.d.proc.poll() is not None:
                    print(d.log_text()[-5000:])
                    return 1
        t_corpus = time.time() - t0
        for c, s in stalls:
            why = run.expect_answers(s, c)
            if not why and not s.closed():
                why = "the daemon did not close the connection"
            s.close()
            if why:
                failed[c.category] += 1
                print("FAIL %s/%s: %s" % (c.category, c.name, why))
        v = run.victim
        v.finish()
        for f in v.failures:
            print("FAIL other client's job: " + f)
        inputs = len(cases) - len([c for c in cases if c.conn == "stall"])
        print("other client's jobs: %d, each completed with the reference's fit: %s; measuring "
              "after %d of %d inputs" % (len(v.jobs), "yes" if not v.failures else "NO",
                                         v.measuring, inputs))
        final = run.alive(after_input=False)
        if final:
            print("FAIL after the corpus: " + final)
            failed["after the corpus"] += 1
        run.status.close()
        run.shared.close()
        v.c.close()
        rc = d.stop()
        if rc != 0 or SANITIZER.search(d.log_text()[run.log_seen:]):
            print("FAIL the daemon stopped with %s:\n%s" % (rc, d.log_text()[-3000:]))
            failed["after the corpus"] += 1
        print()
        print("%-36s %6s %9s" % ("category", "inputs", "answered as documented"))
        for cat, n in per_category.items():
            print("%-36s %6d %9d" % (cat, n, n - failed[cat]))
        bad = sum(failed.values())
        print("%d protocol inputs, %d answered as documented; daemon.status answered %d times; "
              "corpus %.1f s, whole test %.1f s" % (len(cases), len(cases) - sum(
                  failed[c] for c in per_category), run.status_calls, t_corpus, time.time() - t_start))
        return 1 if bad or v.failures else 0
    except Exception:
        print(d.log_text()[-5000:])
        raise
    finally:
        d.cleanup()


if __name__ == "__main__":
    sys.exit(main())
