#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asphd's memory per point and its time from the last point to the result
(docs/daemon.md, "Memory"): jobs of 0.1, 1 and 5 million points on the
strong lens (a Fermat spiral), one after the other, on the mock instrument
without waiting (time_factor 0), through the daemon as a client submits
them. For each job:
- peak: the daemon's peak resident memory while the job runs (VmHWM, its
  mark reset before the job through /proc/PID/clear_refs) less the
  resident memory of the idle daemon before the first job, per point
  (target: at most 300 bytes a point);
- held after: resident memory 2 s after the job completed, less the idle
  daemon's (target: at most 64 MiB);
- last point to result: from the job.progress event that counts the last
  point measured to the job.state event `completed`, every output written,
  per million points (target: at most 5 s per million points), and the
  processor time the daemon spent in it (all its threads; steadier than
  the wall time on a shared machine).
ASPH_BENCH_SIZES (comma-separated point counts) replaces the three sizes."""
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
from daemontest import Client, Daemon, mock_instrument  # noqa: E402

SIZES = [int(v) for v in os.environ.get("ASPH_BENCH_SIZES", "100000,1000000,5000000").split(",")]
TARGET_PEAK_B = 300
TARGET_HELD_MIB = 64
TARGET_S_PER_MILLION = 5.0


def status_kib(pid, key):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    raise KeyError(key)


def cpu_seconds(pid):
    """User and system time of every thread of the process so far."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def reset_peak(pid):
    with open(f"/proc/{pid}/clear_refs", "w") as f:
        f.write("5")


def run_job(c, pid, n):
    """Submits a job of about n points; returns (points, seconds from the
    last point measured to completed, the daemon's processor seconds in
    that time)."""
    c.call("events.subscribe", {"events": ["progress", "job"]})
    job = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": n}})["id"]
    last_point = None
    total = None
    while True:
        msg = c.read_message()
        p = msg.get("params") or {}
        if p.get("job") != job:
            continue
        if msg.get("method") == "job.progress":
            if p["phase"] == "measuring" and p["done"] == p["total"] and last_point is None:
                last_point, cpu0, total = time.monotonic(), cpu_seconds(pid), p["total"]
            elif p["phase"] != "measuring" and last_point is None:
                last_point, cpu0 = time.monotonic(), cpu_seconds(pid)
        elif msg.get("method") == "job.state" and p["state"] in ("completed", "failed", "cancelled"):
            done, cpu = time.monotonic(), cpu_seconds(pid) - cpu0
            if p["state"] != "completed":
                raise RuntimeError(f"job {job} {p['state']}: {p.get('reason')}")
            break
    c.call("events.unsubscribe")
    if total is None:
        total = c.call("job.get", {"id": job})["progress"]["total"]
    return total, done - last_point, cpu


def main():
    d = Daemon([mock_instrument(time_factor=0)])
    miss = False
    try:
        d.start()
        pid = d.proc.pid
        c = Client(d.socket, timeout=3600)
        time.sleep(1)
        idle = status_kib(pid, "VmRSS")
        print(f"idle daemon: {idle / 1024:.1f} MiB resident")
        for n in SIZES:
            reset_peak(pid)
            points, tail, cpu = run_job(c, pid, n)
            peak = status_kib(pid, "VmHWM")
            time.sleep(2)
            held = status_kib(pid, "VmRSS") - idle
            per_point = (peak - idle) * 1024 / points
            per_million = tail / (points / 1e6)
            ok = (per_point <= TARGET_PEAK_B, held / 1024 <= TARGET_HELD_MIB,
                  per_million <= TARGET_S_PER_MILLION)
            miss |= not all(ok)
            print(f"{points} points: peak {(peak - idle) / 1024:.0f} MiB, "
                  f"{per_point:.0f} B/point (target <= {TARGET_PEAK_B}): {'PASS' if ok[0] else 'MISS'}; "
                  f"held after {held / 1024:.1f} MiB (target <= {TARGET_HELD_MIB}): "
                  f"{'PASS' if ok[1] else 'MISS'}; last point to result {tail:.2f} s "
                  f"(processor {cpu:.2f} s), "
                  f"{per_million:.2f} s per million points (target <= {TARGET_S_PER_MILLION}): "
                  f"{'PASS' if ok[2] else 'MISS'}", flush=True)
        c.close()
    finally:
        d.cleanup()
    return 1 if miss else 0


if __name__ == "__main__":
    sys.exit(main())
