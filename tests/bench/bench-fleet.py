#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The cost of the fleet integration (docs/fleet.md), in one run against
its own baseline: bench-daemon (a 20 kHz streaming scan, 32 clients
sending daemon.status) run without and with MQTT publishing to a real
Mosquitto broker and rows for a real PostgreSQL server, through the
outbox, alternately (without, with, without, with, without) so that drift
of the machine falls on both. Targets: the scan's point rate lower by
less than 5 %, daemon.status throughput (with the scan running) by less
than 10 %. The scan's rate while the 32 clients load the daemon is
shown too: on two cores it varies by several per cent between runs.

Then the end-to-end latency of a result: a daemon with both sinks runs
short jobs; for each, from the job's completion (its finish time) to its
row in PostgreSQL (the row's stored_at) and to its result message at a
subscriber (when mosquitto_sub printed it), both from the time of the
job's change to completed as the daemon recorded it (the row's
finished_at). Reported, no target.

Environment: ASPHD_BIN, BENCH_DAEMON (the bench-daemon binary),
ASPH_SOURCE_ROOT; ASPH_BENCH_SECONDS as bench-daemon's."""
import json
import os
import sqlite3
import statistics
import subprocess
import sys
import time

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))
from daemontest import ASPHD, Client, Daemon, mock_instrument  # noqa: E402
from fleettest import Broker, Postgres, Subscriber  # noqa: E402

RUNS = 5
N_LATENCY = 12


def bench_daemon(extra):
    env = dict(os.environ, ASPH_BENCH_NO_BASELINE="1",
               ASPH_BENCH_SECONDS=os.environ.get("ASPH_BENCH_SECONDS", "3"))
    if extra:
        env["ASPH_BENCH_CONFIG"] = ", ".join(f'"{k}": {json.dumps(v)}' for k, v in extra.items())
    p = subprocess.run([os.environ["BENCH_DAEMON"]], capture_output=True, text=True, env=env,
                       timeout=600)
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("figures:")]
    if p.returncode != 0 or not line:
        raise RuntimeError(f"bench-daemon failed ({p.returncode}): {p.stdout}{p.stderr}")
    f = line[0].split()[1:]
    return {f[i]: float(f[i + 1]) for i in range(0, len(f), 2)}


broker = Broker()
pg = Postgres()
misses = 0
try:
    fleet = {"mqtt": {"url": broker.url(), "prefix": "bench/fleet", "qos": 1},
             "postgres": {"conninfo": pg.conninfo}}
    probe = Daemon(extra={"postgres": fleet["postgres"]})
    m = subprocess.run([ASPHD, "--db-migrate", "--config", probe.config], capture_output=True,
                       text=True)
    probe.cleanup()
    if m.returncode != 0:
        raise RuntimeError(f"--db-migrate: {m.stderr}")
    sub = Subscriber(broker, "bench/#")

    runs = {"without": [], "with": []}
    for i in range(RUNS):
        kind = "without" if i % 2 == 0 else "with"
        runs[kind].append(bench_daemon(fleet if kind == "with" else None))
    mean = {k: {key: statistics.mean(r[key] for r in v) for key in v[0]} for k, v in runs.items()}
    progress = len([x for x in sub.messages("bench/fleet/job/") if x["topic"].endswith("/progress")])
    for k in ("without", "with"):
        print(f"{k:7} MQTT and PostgreSQL ({len(runs[k])} runs): scan "
              f"{mean[k]['points_per_s']:.0f} points/s, daemon.status {mean[k]['rps']:.0f} "
              f"requests/s (p99 {mean[k]['p99_ms']:.3f} ms), scan under that load "
              f"{mean[k]['points_per_s_loaded']:.0f} points/s")
    print(f"the runs with MQTT published {progress} progress messages to the broker")
    drop_scan = 1 - mean["with"]["points_per_s"] / mean["without"]["points_per_s"]
    drop_loaded = 1 - mean["with"]["points_per_s_loaded"] / mean["without"]["points_per_s_loaded"]
    drop_rps = 1 - mean["with"]["rps"] / mean["without"]["rps"]
    print(f"scan point rate with/without: {1 - drop_scan:.3f} ({100 * drop_scan:.1f} % lower, "
          f"target < 5 %): {'PASS' if drop_scan < 0.05 else 'MISS'}")
    # Two cores shared by the scan, the daemon's loop and 32 busy clients:
    # this one varies by several per cent from run to run, and is shown.
    print(f"scan point rate under daemon.status load, with/without: {1 - drop_loaded:.3f} "
          f"({100 * drop_loaded:.1f} % lower; no target)")
    print(f"daemon.status throughput with/without: {1 - drop_rps:.3f} ({100 * drop_rps:.1f} % "
          f"lower, target < 10 %): {'PASS' if drop_rps < 0.10 else 'MISS'}")
    misses += (drop_scan >= 0.05) + (drop_rps >= 0.10)
    misses += progress == 0

    # --- end-to-end latency of a result
    d = Daemon(instruments=[mock_instrument(time_factor=0.002)],
               extra={"mqtt": dict(fleet["mqtt"], prefix="bench/latency"),
                      "postgres": fleet["postgres"]})
    d.start()
    c = Client(d.socket)
    c.call("events.subscribe", {"events": ["job"]})
    jobs = [c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 100}})["id"]
            for _ in range(N_LATENCY)]
    for j in jobs:
        c.wait_state(j, ["completed"])
    db = sqlite3.connect(os.path.join(d.state, "jobs.sqlite"))
    did = db.execute("SELECT value FROM meta WHERE key = 'daemon.id'").fetchone()[0]
    db.close()
    deadline = time.time() + 60
    while time.time() < deadline:
        got = {x["payload"]["job"] for x in sub.messages("bench/latency/job/")
               if x["topic"].endswith("/result")}
        rows = pg.psql("SELECT job_id, extract(epoch FROM stored_at), "
                       "extract(epoch FROM finished_at) FROM asphd.results "
                       f"WHERE daemon_id = '{did}'")
        if set(jobs) <= got and len(rows) >= len(jobs):
            break
        time.sleep(0.1)
    # the time of the change to completed, as the daemon recorded it
    finished = {int(r[0]): float(r[2]) for r in rows}
    stored = {int(r[0]): float(r[1]) for r in rows}
    received = {}
    for x in sub.messages("bench/latency/job/"):
        if x["topic"].endswith("/result"):
            received.setdefault(x["payload"]["job"], x["received"])
    to_row = sorted((stored[j] - finished[j]) * 1e3 for j in jobs if j in stored)
    to_msg = sorted((received[j] - finished[j]) * 1e3 for j in jobs if j in received)
    print(f"end-to-end result latency over {len(jobs)} jobs (daemon, broker and database on "
          f"this machine):")
    print(f"  job completed -> row in PostgreSQL: median {statistics.median(to_row):.1f} ms, "
          f"max {to_row[-1]:.1f} ms ({len(to_row)} rows)")
    print(f"  job completed -> result message at a subscriber: median "
          f"{statistics.median(to_msg):.1f} ms, max {to_msg[-1]:.1f} ms ({len(to_msg)} messages)")
    misses += len(to_row) != len(jobs) or len(to_msg) != len(jobs)
    c.close()
    d.stop()
    d.cleanup()
    sub.close()
finally:
    broker.cleanup()
    pg.cleanup()
sys.exit(1 if misses else 0)
