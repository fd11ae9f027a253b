#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Soak test: asphd measures job after job with the mock instrument at full
speed while 32 clients poll and 8 listen to every event. After the warm-up
the daemon's resident memory must show no trend of 1 MB (and no peak 16 MB
above where it was: a job's report picture comes and goes), its descriptor
count must come back to where it started, and every submitted job must
complete.

With --attacks S the security reviews' attacks (tests/security/attacks.py)
run in rotation, each for S seconds and then 5 s of quiet, over the web
page and TCP as a viewer; the pollers' latency is reported per attack (it
is measured in this process, beside the attackers' threads, so it holds
Python's own delays: the benchmark `daemon` measures the daemon's), and the
memory checks apply to the resident memory in the quiet after each attack
(an estimate of 4.9 M points is allowed its transient plan). With --mqtt
the daemon publishes to a Mosquitto broker started here: the outbox's
waiting messages are sampled over time (GET /metrics) and every completed
job's result must arrive at a subscriber. Every completed job's result is
read back from the daemon at the end.

  soak.py [--duration S] [--warmup S] [--clients N] [--subscribers N]
          [--points N] [--sample S] [--attacks S] [--mqtt] [--report FILE]

Exit 0 when every check holds, 1 otherwise (suite 'soak')."""
import argparse
import json
import os
import sys
import threading
import time
import urllib.request

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
sys.path.insert(0, os.path.join(HERE, "..", "security"))
from daemontest import Client, Daemon, expect, finish, free_port, mock_instrument, web_port  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(HERE, "..", ".."))
PREFIX = "lab/soak"
QUIET_S = 5
# What a job may hold for a moment above the daemon's steady memory: the
# PDF report paints its residual map as one 300 dpi picture (lib/plot,
# several MB, with cairo's copy of it for the page), made and freed within
# each job. A leak shows as the trend, which stays under 1 MB.
PEAK_KB = 16 * 1024


def proc_figures(pid):
    """(VmRSS in kB, open descriptors, threads) of pid."""
    rss = threads = 0
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                rss = int(line.split()[1])
            elif line.startswith("Threads:"):
                threads = int(line.split()[1])
    return rss, len(os.listdir(f"/proc/{pid}/fd")), threads


class Stats:
    def __init__(self):
        self.lock = threading.Lock()
        self.requests = 0
        self.errors = []
        self.events = {}
        self.phase = "no attack"
        self.latency = {}   # phase -> histogram of the pollers' answers, 1 ms buckets

    def answered(self, seconds):
        with self.lock:
            self.requests += 1
            h = self.latency.setdefault(self.phase, [0] * 10001)
            h[min(10000, int(seconds * 1000))] += 1

    def percentiles(self):
        """phase -> (answers, p50 ms, p99 ms, worst ms), from the histograms."""
        out = {}
        with self.lock:
            for phase, h in self.latency.items():
                n = sum(h)
                def at(q, h=h, n=n):
                    k, acc = 0, 0
                    for k, c in enumerate(h):
                        acc += c
                        if acc >= q * n:
                            break
                    return k
                worst = max(k for k, c in enumerate(h) if c)
                out[phase] = {"answers": n, "p50_ms": at(0.5), "p99_ms": at(0.99), "max_ms": worst}
        return out

    def error(self, what):
        with self.lock:
            if len(self.errors) < 20:
                self.errors.append(what)


def poller(path, stop, stats, k):
    """Reads the daemon's state in a loop, as a status display would."""
    calls = [("daemon.status", None), ("job.list", {"limit": 20}), ("queue.get", None),
             ("instrument.list", None), ("job.list", {"states": ["running"]})]
    try:
        c = Client(path, timeout=60)
        i = k
        while not stop.is_set():
            method, params = calls[i % len(calls)]
            i += 1
            t0 = time.monotonic()
            c.call(method, params)
            stats.answered(time.monotonic() - t0)
            time.sleep(0.05)
        c.close()
    except Exception as e:  # any failure of a poller is a finding
        stats.error(f"poller {k}: {e!r}")


def subscriber(path, stop, stats, k):
    """Listens to every event class until stopped."""
    try:
        c = Client(path, timeout=1)
        c.sock.settimeout(60)
        c.call("events.subscribe", {})
        c.sock.settimeout(0.5)
        n = 0
        while not stop.is_set():
            try:
                c.next_event()
                n += 1
            except TimeoutError:
                continue
        with stats.lock:
            stats.events[k] = n
        c.close()
    except Exception as e:
        stats.error(f"subscriber {k}: {e!r}")


def outbox_waiting(port, token):
    """asphd_outbox_messages of the mqtt sink, from GET /metrics."""
    req = urllib.request.Request(f"http://127.0.0.1:{port}/metrics",
                                 headers={"Authorization": f"Bearer {token}"})
    with urllib.request.urlopen(req, timeout=60) as r:
        for line in r.read().decode().splitlines():
            if line.startswith('asphd_outbox_messages{sink="mqtt"}'):
                return int(float(line.split()[-1]))
    return None


def rotation(ctx, pid, stop, stats, seconds, quiet):
    """The attacks one after the other until stopped; after each, QUIET_S
    of quiet and a sample of the daemon's figures."""
    from attacks import ATTACKS
    attacks = ATTACKS[1:]   # the first is the benchmark's baseline: no attack
    while not stop.is_set():
        for what, attack in attacks:
            if stop.is_set():
                return
            loads = attack(ctx)
            with stats.lock:
                stats.phase = what
            for load in loads:
                load.start()
            stop.wait(seconds)
            for load in loads:
                load.done.set()
            for load in loads:
                load.join(timeout=60)
            with stats.lock:
                stats.phase = "no attack"
            stop.wait(QUIET_S)
            rss, fds, nthreads = proc_figures(pid)
            quiet.append({"t": round(time.time() - ctx["t0"], 1), "after": what, "rss_kb": rss,
                          "fds": fds, "threads": nthreads})


def poll_jobs(sub, outstanding, completed, other):
    """The outstanding jobs that ended leave the set for completed or other."""
    for j in list(outstanding):
        st = sub.call("job.get", {"id": j})["state"]
        if st == "completed":
            completed.append(j)
        elif st in ("failed", "cancelled", "interrupted"):
            other.append((j, st))
        else:
            continue
        outstanding.discard(j)


def wait_jobs(sub, outstanding, completed, other, deadline):
    while outstanding and time.time() < deadline:
        poll_jobs(sub, outstanding, completed, other)
        time.sleep(0.05)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=300)
    ap.add_argument("--warmup", type=float, default=60)
    ap.add_argument("--clients", type=int, default=32)
    ap.add_argument("--subscribers", type=int, default=8)
    ap.add_argument("--points", type=int, default=1000)
    ap.add_argument("--sample", type=float, default=5)
    ap.add_argument("--attacks", type=float, default=0,
                    help="the attacks in rotation, each this many seconds (0: none)")
    ap.add_argument("--mqtt", action="store_true", help="publish to a Mosquitto broker started here")
    ap.add_argument("--report")
    a = ap.parse_args()
    if os.environ.get("ASPH_WRAPPER"):
        print("SKIP: the soak test measures the daemon's own memory, not a wrapper's")
        sys.exit(77)

    extra, broker, results = {}, None, None
    web = a.attacks > 0 or a.mqtt
    if web:
        tcp = free_port()
        extra.update({"http_listen": "127.0.0.1:0", "http_root": os.path.join(ROOT, "daemon", "web"),
                      "tcp_listen": f"127.0.0.1:{tcp}"})
    if a.mqtt:
        from fleettest import Broker, Subscriber
        broker = Broker()
        extra["mqtt"] = {"url": broker.url(), "prefix": PREFIX, "qos": 1}
        results = Subscriber(broker, f"{PREFIX}/job/+/result")
    d = Daemon(instruments=[mock_instrument(time_factor=0)], extra=extra)
    stop = threading.Event()
    stats = Stats()
    samples, quiet = [], []
    try:
        d.start()
        pid = d.proc.pid
        time.sleep(0.3)
        ctx = {}
        if web:
            admin = Client(d.socket, timeout=120)
            ctx.update({"web": web_port(d), "tcp": tcp,
                        "viewer": admin.call("token.create", {"name": "soak-viewer", "role": "viewer"})["token"]})
            admin.close()
            time.sleep(0.3)
        fds_idle = proc_figures(pid)[1]
        sub = Client(d.socket, timeout=120)
        ctx["t0"] = time.time()
        threads = [threading.Thread(target=poller, args=(d.socket, stop, stats, k), daemon=True)
                   for k in range(a.clients)]
        threads += [threading.Thread(target=subscriber, args=(d.socket, stop, stats, k), daemon=True)
                    for k in range(a.subscribers)]
        for t in threads:
            t.start()
        attacker = None
        if a.attacks > 0:
            attacker = threading.Thread(target=rotation, args=(ctx, pid, stop, stats, a.attacks, quiet),
                                        daemon=True)
            attacker.start()

        # The submitter keeps two jobs ahead of the instrument.
        spec = {"lens": "strong", "plan": {"method": "fermat", "points": a.points}}
        outstanding = set()
        submitted = 0
        completed, other = [], []
        t0 = ctx["t0"]
        next_sample = t0
        while time.time() - t0 < a.duration:
            while len(outstanding) < 2:
                outstanding.add(sub.call("job.submit", spec)["id"])
                submitted += 1
            poll_jobs(sub, outstanding, completed, other)
            now = time.time()
            if now >= next_sample:
                rss, fds, nthreads = proc_figures(pid)
                sample = {"t": round(now - t0, 1), "rss_kb": rss, "fds": fds, "threads": nthreads,
                          "jobs": len(completed), "phase": stats.phase}
                if a.mqtt:
                    sample["outbox"] = outbox_waiting(ctx["web"], ctx["viewer"])
                samples.append(sample)
                if a.report:  # the figures so far, for a run watched from outside
                    with open(a.report + ".partial", "w") as f:
                        json.dump({"samples": samples, "quiet": quiet}, f)
                next_sample += a.sample
            time.sleep(0.01)
        stop.set()
        if attacker:
            attacker.join(timeout=120)
        # Let the last jobs finish, then count.
        wait_jobs(sub, outstanding, completed, other, time.time() + 120)
        rss_end, fds_busy, _ = proc_figures(pid)
        for t in threads:
            t.join(timeout=30)
        status = sub.call("daemon.status")
        total = sub.call("job.list", {"limit": 1})["total"]
        # Every result can be read back, and (--mqtt) every one left the PC.
        unreadable = []
        for j in completed:
            res = sub.call("job.result", {"id": j})
            if "summary" not in res or not os.path.exists(os.path.join(res["dir"], "result.json")):
                unreadable.append(j)
        published, outbox_end = None, None
        if a.mqtt:
            deadline = time.time() + 300
            while time.time() < deadline and outbox_waiting(ctx["web"], ctx["viewer"]):
                time.sleep(1)
            outbox_end = outbox_waiting(ctx["web"], ctx["viewer"])
            want = {str(j) for j in completed}
            got = lambda: {m["topic"].split("/")[-2] for m in results.messages()}  # noqa: E731
            deadline = time.time() + 120
            while time.time() < deadline and not want <= got():
                time.sleep(1)
            published = len(want & got())
        sub.close()
        time.sleep(0.5)
        _, fds_after, _ = proc_figures(pid)
        elapsed = time.time() - t0

        # A leak is a trend: the floor of the last third of the samples
        # against the first third's. A peak is allowed more: plans and
        # estimates run on worker threads, whose malloc arenas come and go.
        # Under the attacks the samples are those of the quiet after each.
        steady = quiet if a.attacks > 0 else samples
        warm = [s for s in steady if s["t"] >= a.warmup]
        base = warm[0]["rss_kb"] if warm else steady[-1]["rss_kb"]
        peak = max(s["rss_kb"] for s in warm) if warm else base
        # The floor of a third is its 10th percentile: the memory between
        # jobs. A sample taken while a job's report picture is live sits
        # several MB higher, and how many samples land there is chance.
        third = max(1, len(warm) // 3)
        floor = lambda xs: sorted(xs)[len(xs) // 10]  # noqa: E731
        trend = (floor([s["rss_kb"] for s in warm[-third:]]) -
                 floor([s["rss_kb"] for s in warm[:third]])) if warm else 0
        fig = {
            "duration_s": round(elapsed), "jobs_submitted": submitted, "jobs_completed": len(completed),
            "jobs_per_s": round(len(completed) / elapsed, 2), "requests": stats.requests,
            "requests_per_s": round(stats.requests / elapsed), "events": sum(stats.events.values()),
            "rss_start_kb": samples[0]["rss_kb"], "rss_after_warmup_kb": base, "rss_peak_kb": peak,
            "rss_peak_any_kb": max(s["rss_kb"] for s in samples),
            "rss_end_kb": rss_end, "rss_growth_kb": peak - base, "rss_trend_kb": trend,
            "fds_idle": fds_idle, "fds_busy_max": max(s["fds"] for s in samples),
            "fds_busy_end": fds_busy, "fds_after": fds_after,
            "threads_max": max(s["threads"] for s in samples), "latency": stats.percentiles(),
            "results_unreadable": len(unreadable),
        }
        if a.mqtt:
            fig.update({"outbox_max": max(s["outbox"] or 0 for s in samples), "outbox_end": outbox_end,
                        "results_published": published})
        if a.attacks > 0:
            fig["attack_rounds"] = len(quiet)
        print(json.dumps(fig, indent=1))
        fig["samples"], fig["quiet"] = samples, quiet
        if a.report:
            with open(a.report, "w") as f:
                json.dump(fig, f, indent=1)
        expect(not stats.errors, f"every client was served ({stats.errors})")
        expect(len(completed) == submitted and not other and not outstanding,
               f"no job lost: {len(completed)} of {submitted} completed ({other[:5]}, {len(outstanding)} left)")
        expect(total == submitted and status["jobs"]["completed"] == submitted,
               f"the store holds every job ({total}, {status['jobs']})")
        expect(not unreadable, f"every completed job's result reads back ({unreadable[:5]})")
        if a.mqtt:
            expect(outbox_end == 0 and published == len(completed),
                   f"every result left through the outbox ({published} of {len(completed)} at the "
                   f"subscriber, {outbox_end} waiting)")
        expect(len(stats.events) == a.subscribers and all(n > 0 for n in stats.events.values()),
               f"every subscriber received events ({sorted(stats.events.values())})")
        expect(trend < 1024, f"RSS trend after the warm-up under 1 MB ({trend} kB, the last third's "
               f"floor against the first's; {base} -> peak {peak}, end {rss_end})")
        expect(peak - base < PEAK_KB, f"RSS peak after the warm-up under {PEAK_KB // 1024} MB above its start "
               f"({peak - base} kB: {base} -> peak {peak}, end {rss_end})")
        expect(fds_after == fds_idle, f"no descriptor leak ({fds_idle} before the clients, {fds_after} after)")
        expect(d.stop() == 0, "clean stop after the soak")
    except Exception:
        print(d.log_text()[-5000:])
        raise
    finally:
        stop.set()
        d.cleanup()
        if results:
            results.close()
        if broker:
            broker.cleanup()
    finish()


main()
