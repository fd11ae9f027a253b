#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Soak test: asphd measures job after job with the mock instrument at full
speed while 32 clients poll and 8 listen to every event. After the warm-up
the daemon's resident memory must show no trend of 1 MB (and no peak 4 MB
above where it was), its descriptor
count must come back to where it started, and every submitted job must
complete.

  soak.py [--duration S] [--warmup S] [--clients N] [--subscribers N]
          [--points N] [--report FILE]

Exit 0 when every check holds, 1 otherwise (suite 'soak')."""
import argparse
import json
import os
import sys
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "integration"))
from daemontest import Client, Daemon, expect, finish, mock_instrument  # noqa: E402


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
            c.call(method, params)
            with stats.lock:
                stats.requests += 1
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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=300)
    ap.add_argument("--warmup", type=float, default=60)
    ap.add_argument("--clients", type=int, default=32)
    ap.add_argument("--subscribers", type=int, default=8)
    ap.add_argument("--points", type=int, default=1000)
    ap.add_argument("--sample", type=float, default=5)
    ap.add_argument("--report")
    a = ap.parse_args()
    if os.environ.get("ASPH_WRAPPER"):
        print("SKIP: the soak test measures the daemon's own memory, not a wrapper's")
        sys.exit(77)

    d = Daemon(instruments=[mock_instrument(time_factor=0)])
    stop = threading.Event()
    stats = Stats()
    samples = []
    try:
        d.start()
        pid = d.proc.pid
        time.sleep(0.3)
        fds_idle = proc_figures(pid)[1]
        threads = [threading.Thread(target=poller, args=(d.socket, stop, stats, k), daemon=True)
                   for k in range(a.clients)]
        threads += [threading.Thread(target=subscriber, args=(d.socket, stop, stats, k), daemon=True)
                    for k in range(a.subscribers)]
        for t in threads:
            t.start()

        # The submitter keeps two jobs ahead of the instrument.
        sub = Client(d.socket, timeout=120)
        spec = {"lens": "strong", "plan": {"method": "fermat", "points": a.points}}
        outstanding = set()
        submitted = completed = 0
        other = []
        t0 = time.time()
        next_sample = t0
        while time.time() - t0 < a.duration:
            while len(outstanding) < 2:
                outstanding.add(sub.call("job.submit", spec)["id"])
                submitted += 1
            for j in list(outstanding):
                st = sub.call("job.get", {"id": j})["state"]
                if st in ("completed", "failed", "cancelled", "interrupted"):
                    outstanding.discard(j)
                    if st == "completed":
                        completed += 1
                    else:
                        other.append((j, st))
            now = time.time()
            if now >= next_sample:
                rss, fds, nthreads = proc_figures(pid)
                samples.append({"t": round(now - t0, 1), "rss_kb": rss, "fds": fds, "threads": nthreads,
                                "jobs": completed})
                if a.report:  # the figures so far, for a run watched from outside
                    with open(a.report + ".partial", "w") as f:
                        json.dump(samples, f)
                next_sample += a.sample
            time.sleep(0.01)
        # Let the last jobs finish, then count.
        deadline = time.time() + 120
        while outstanding and time.time() < deadline:
            for j in list(outstanding):
                st = sub.call("job.get", {"id": j})["state"]
                if st in ("completed", "failed", "cancelled", "interrupted"):
                    outstanding.discard(j)
                    completed += st == "completed"
                    if st != "completed":
                        other.append((j, st))
            time.sleep(0.05)
        rss_end, fds_busy, _ = proc_figures(pid)
        stop.set()
        for t in threads:
            t.join(timeout=30)
        status = sub.call("daemon.status")
        total = sub.call("job.list", {"limit": 1})["total"]
        sub.close()
        time.sleep(0.5)
        _, fds_after, _ = proc_figures(pid)
        elapsed = time.time() - t0

        warm = [s for s in samples if s["t"] >= a.warmup]
        base = warm[0]["rss_kb"] if warm else samples[-1]["rss_kb"]
        peak = max(s["rss_kb"] for s in warm) if warm else base
        # A leak is a trend: the median of the last third of the samples
        # against the first third's. A peak is allowed more: plans and
        # estimates run on worker threads, whose malloc arenas come and go.
        third = max(1, len(warm) // 3)
        median = lambda xs: sorted(xs)[len(xs) // 2]
        trend = (median([s["rss_kb"] for s in warm[-third:]]) -
                 median([s["rss_kb"] for s in warm[:third]])) if warm else 0
        fig = {
            "duration_s": round(elapsed), "jobs_submitted": submitted, "jobs_completed": completed,
            "jobs_per_s": round(completed / elapsed, 2), "requests": stats.requests,
            "requests_per_s": round(stats.requests / elapsed), "events": sum(stats.events.values()),
            "rss_start_kb": samples[0]["rss_kb"], "rss_after_warmup_kb": base, "rss_peak_kb": peak,
            "rss_end_kb": rss_end, "rss_growth_kb": peak - base, "rss_trend_kb": trend,
            "fds_idle": fds_idle, "fds_busy_max": max(s["fds"] for s in samples),
            "fds_busy_end": fds_busy, "fds_after": fds_after,
            "threads_max": max(s["threads"] for s in samples), "samples": samples,
        }
        print(json.dumps({k: v for k, v in fig.items() if k != "samples"}, indent=1))
        if a.report:
            with open(a.report, "w") as f:
                json.dump(fig, f, indent=1)
        expect(not stats.errors, f"every client was served ({stats.errors})")
        expect(completed == submitted and not other and not outstanding,
               f"no job lost: {completed} of {submitted} completed ({other[:5]}, {len(outstanding)} left)")
        expect(total == submitted and status["jobs"]["completed"] == submitted,
               f"the store holds every job ({total}, {status['jobs']})")
        expect(len(stats.events) == a.subscribers and all(n > 0 for n in stats.events.values()),
               f"every subscriber received events ({sorted(stats.events.values())})")
        expect(trend < 1024, f"RSS trend after the warm-up under 1 MB ({trend} kB, the last third's "
               f"median against the first's; {base} -> peak {peak}, end {rss_end})")
        expect(peak - base < 4096, f"RSS peak after the warm-up under 4 MB above its start "
               f"({peak - base} kB: {base} -> peak {peak}, end {rss_end})")
        expect(fds_after == fds_idle, f"no descriptor leak ({fds_idle} before the clients, {fds_after} after)")
        expect(d.stop() == 0, "clean stop after the soak")
    except Exception:
        print(d.log_text()[-5000:])
        raise
    finally:
        stop.set()
        d.cleanup()
    finish()


main()
