#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""High 1 of the security review: one request line from a reader must not
drive the daemon to gigabytes or stall it.

The exact attack: with about 2,000 jobs in the store (seeded into the
SQLite store directly, as copies of one real job), a user who may only
read sends one line, a batch of 1,000 job.list calls with limit 1000; then
a batch of 1,000 driver.list, as on a fresh install; then the first batch
20 times in a row, sent before the first answer is read. Throughout, another client asks
daemon.status every 50 ms, and the daemon's RSS and its watchdog pings
(WATCHDOG=1 on a NOTIFY_SOCKET of the test's, WATCHDOG_USEC 2 s) are
watched. Checked: every request gets its answer (a job.list of 1,000 jobs,
or -32004 once the line's answers pass limits.max_response_bytes, naming
it), the daemon's RSS stays under 256 MiB and comes back within 32 MiB of
where it was, no daemon.status waits 1 s or more, and the watchdog is fed
at least every second.

Under valgrind (ASPH_UNDER_VALGRIND) memory and time mean nothing: the
answers are checked, the bounds are not (the output says so), and the
pipelined round is left out. Built with AddressSanitizer, the daemon's RSS
is mostly ASan's (its quarantine keeps what is freed): the memory bounds
are left out, the time bounds kept."""
import json
import os
import signal
import time

from seclib import (SANITIZED, UNDER_VALGRIND, Accounts, Notify, Poller, Sampler, expect, finish,
                    rss_kib, seed_jobs, tempdir)
from daemontest import Client, Daemon, mock_instrument

RSS_BOUND_KIB = 256 * 1024
SETTLE_KIB = 32 * 1024
JOBS = 2000
WATCHDOG_USEC = 2000000

# The reader's program: sends argv[2] copies of stdin's line at once (a
# thread writes them while the answers are read) and reads as many answers,
# each one line; prints what came back.
ATTACK = r'''
import json, socket, sys, threading, time
s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1])
line, copies = sys.stdin.buffer.read(), int(sys.argv[2])
t0 = time.monotonic()
threading.Thread(target=lambda: s.sendall(line * copies), daemon=True).start()
buf, answers, size = b"", [], 0
while len(answers) < copies:
    chunk = s.recv(1 << 20)
    if not chunk:
        break
    buf += chunk
    while b"\n" in buf:
        one, buf = buf.split(b"\n", 1)
        size += len(one) + 1
        a = json.loads(one)
        kinds = {"result": 0, "refused": 0, "other": []}
        for r in a if isinstance(a, list) else [a]:
            if "result" in r:
                kinds["result"] += 1
                kinds.setdefault("listed", len(r["result"].get("jobs", r["result"].get("drivers", []))))
            elif r.get("error", {}).get("code") == -32004:
                kinds["refused"] += 1
                kinds["detail"] = r["error"]["data"]["detail"]
            else:
                kinds["other"].append(r)
        kinds["ids"] = sorted(r.get("id") for r in a) if isinstance(a, list) else None
        answers.append(kinds)
print(json.dumps({"answers": answers, "seconds": time.monotonic() - t0, "bytes": size}))
'''


def batch(method, params, n=1000):
    return (json.dumps([{"jsonrpc": "2.0", "id": i, "method": method, "params": params}
                        for i in range(n)], separators=(",", ":")) + "\n").encode()


def gaps(times, start, end):
    inside = [t for t in times if start <= t <= end]
    edges = [start] + inside + [end]
    return max(b - a for a, b in zip(edges, edges[1:]))


accounts = Accounts()
_, lab = accounts.group("lab")          # may open the socket: a reader
reader = accounts.user("read", [lab])
top = tempdir()
notify = Notify(top)
os.mkdir(os.path.join(top, "d"))
d = Daemon(instruments=[mock_instrument()], top=os.path.join(top, "d"), extra={"socket_group": lab})
try:
    n = seed_jobs(d, JOBS, 3)
    expect(n == JOBS, f"{n} jobs in the store")

    os.environ["NOTIFY_SOCKET"] = notify.path
    os.environ["WATCHDOG_USEC"] = str(WATCHDOG_USEC)
    d.start()
    del os.environ["NOTIFY_SOCKET"], os.environ["WATCHDOG_USEC"]
    pid = d.proc.pid
    c = Client(d.socket)
    expect(c.call("daemon.status")["jobs"]["completed"] == JOBS, f"the daemon counts {JOBS} completed jobs")
    time.sleep(0.5)
    before, _ = rss_kib(pid)
    budget = 4 << 20

    rounds = [("1,000 x job.list limit 1000", batch("job.list", {"limit": 1000}), 1),
              ("1,000 x driver.list", batch("driver.list", {}), 1)]
    if not UNDER_VALGRIND:
        rounds.append(("the job.list batch 20 times, pipelined", batch("job.list", {"limit": 1000}), 20))
    for what, line, copies in rounds:
        poller, sampler = Poller(d.socket), Sampler(pid)
        poller.start()
        sampler.start()
        t0 = time.monotonic()
        out = reader.python(ATTACK, d.socket, copies, stdin=line.decode(), timeout=1200)
        t1 = time.monotonic()
        time.sleep(0.3)
        poller.stop()
        peak = sampler.stop()
        answers = out["answers"]
        expect(len(answers) == copies, f"{what}: {len(answers)} answer line(s) of {copies}")
        for a in answers:
            expect(a["ids"] == list(range(1000)) and not a["other"] and a["result"] + a["refused"] == 1000,
                   f"{what}: every request answered in one array, by its id "
                   f"({a['result']} carried out, {a['refused']} refused)")
        a = answers[0]
        expect(a["result"] >= 1 and a["refused"] >= 1 and "max_response_bytes" in a.get("detail", ""),
               f"{what}: past the budget -32004 naming limits.max_response_bytes ({a.get('detail')})")
        expect(out["bytes"] <= copies * (budget + 1000 * 300 + (1 << 20)),
               f"{what}: {out['bytes'] / 1e6:.1f} MB of answers for {copies} line(s), "
               f"{out['seconds']:.2f} s")
        lat = [x for x in poller.latencies if x is not None]
        failed = len(poller.latencies) - len(lat)
        worst = max(lat, default=0)
        dog = gaps(notify.times("WATCHDOG=1"), t0, t1)
        after, _ = rss_kib(pid)
        print(f"# {what}: RSS {before / 1024:.1f} MiB before, peak {peak / 1024:.1f} MiB, "
              f"{after / 1024:.1f} MiB after; daemon.status {len(lat)} answers, p50 "
              f"{sorted(lat)[len(lat) // 2] * 1e3 if lat else 0:.1f} ms, worst {worst * 1e3:.1f} ms; "
              f"longest watchdog gap {dog * 1e3:.0f} ms; {out['seconds']:.2f} s")
        expect(failed == 0 and len(lat) > 0, f"{what}: another client answered throughout ({failed} failed)")
        if UNDER_VALGRIND:
            print(f"# under valgrind: the bounds on RSS, latency and the watchdog are not checked")
            continue
        if SANITIZED:
            print("# built with AddressSanitizer: the bounds on RSS are not checked")
        else:
            expect(peak < RSS_BOUND_KIB, f"{what}: RSS peak {peak / 1024:.1f} MiB < 256 MiB")
            expect(after < before + SETTLE_KIB, f"{what}: RSS back to {after / 1024:.1f} MiB "
                   f"(within 32 MiB of {before / 1024:.1f})")
        expect(worst < 1.0, f"{what}: daemon.status answered within 1 s ({worst * 1e3:.0f} ms at worst)")
        expect(dog < 1.2, f"{what}: the watchdog was fed (longest gap {dog * 1e3:.0f} ms, "
               f"pings due every {WATCHDOG_USEC / 2e6:.1f} s)")
    expect(d.proc.poll() is None and c.call("version")["server"] == "asphd", "the daemon still serves")
    c.close()
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text()[-4000:])
    raise
finally:
    notify.close()
    d.cleanup()
finish()
