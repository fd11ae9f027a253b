#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Fault campaign: ROUNDS times, asphd starts with a healthy mock
instrument and FAULTS instruments that each fail at a random reading
(seeded): the mock probe's own faults (disconnect, timeout, out of range)
and a Modbus TCP sensor simulator on a loopback port behind the mock stage
(garbage answers, a stalled sensor, a dropped connection). One job on
each, all at once. Every faulty job must end failed with the fault as its
reason, its instrument must report the fault and measure nothing more,
the recorded scan must hold exactly the points reported measured (and end
with the same reason), an instrument.fault event must tell subscribers,
the healthy instrument's job must complete, and the daemon must go on
answering and measuring.

  faults.py [--rounds N] [--faults N] [--seed S] [--report FILE]"""
import argparse
import json
import os
import random
import re
import sys
import time

from chaoslib import ModbusSensor, scan_info, store_check
from daemontest import Client, Daemon, expect, finish, mock_instrument

POINTS = 1200
SPEC = {"lens": "strong", "plan": {"method": "fermat", "points": POINTS}}
# What each fault's reason must say.
KINDS = {
    "disconnect": r"disconnected after \d+ readings",
    "timeout": r"did not answer reading \d+",
    "out-of-range": r"out of range",
    "garbage": r"127\.0\.0\.1:\d+: .*(does not fit|bad|invalid|Invalid|did not answer|connection lost)",
    "stall": r"127\.0\.0\.1:\d+: unit 1 did not answer",
    "drop": r"127\.0\.0\.1:\d+: .*(connection lost|refused|Connection)",
}
MOCK = {"disconnect": "fail_after", "timeout": "timeout_at", "out-of-range": "out_of_range_at"}


def instrument(name, kind, at, seed, sims):
    if kind in MOCK:
        return mock_instrument(name, **{MOCK[kind]: at})
    sim = ModbusSensor(kind, at, seed)
    sims.append(sim)
    return {"name": name, "stage": {"driver": "mock", "options": {"time_factor": 0.02}},
            "probe": {"driver": "modbus", "options": {"transport": "tcp", "host": "127.0.0.1",
                                                      "port": sim.port, "timeout": 100, "retries": 1}}}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--faults", type=int, default=6)
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--report")
    a = ap.parse_args()
    rng = random.Random(a.seed)
    fig = {"rounds": 0, "faults": 0, "by_kind": {k: 0 for k in KINDS}, "seed": a.seed}
    for r in range(a.rounds):
        sims = []
        plan = [(f"f{i}", rng.choice(list(KINDS)), rng.randint(1, POINTS - 100)) for i in range(a.faults)]
        insts = [mock_instrument("healthy")]
        insts += [instrument(name, kind, at, rng.randrange(1 << 30), sims) for name, kind, at in plan]
        d = Daemon(instruments=insts)
        try:
            d.start()
            c = Client(d.socket)
            ev = Client(d.socket)
            ev.call("events.subscribe", {"events": ["instrument"]})
            healthy = c.call("job.submit", dict(SPEC, instrument="healthy"))["id"]
            jobs = {name: c.call("job.submit", dict(SPEC, instrument=name))["id"] for name, _, _ in plan}
            deadline = time.time() + 300
            for name, kind, at in plan:
                job = jobs[name]
                while time.time() < deadline:
                    j = c.call("job.get", {"id": job})
                    if j["state"] not in ("queued", "running"):
                        break
                    time.sleep(0.05)
                what = f"round {r}: {kind} at {at} on {name}"
                reason = j["reason"] or ""
                expect(j["state"] == "failed" and re.search(KINDS[kind], reason),
                       f"{what}: failed with the reason ({j['state']}: {reason})")
                st = c.call("instrument.status", {"name": name})
                expect(st["state"] == "fault" and st["job"] is None and st["fault"] == reason,
                       f"{what}: the instrument reports the fault and measures nothing ({st['state']})")
                info = scan_info(os.path.join(d.state, "jobs", str(job), "scan.asphscan"))
                if info is None:
                    expect(j["progress"]["done"] == 0, f"{what}: no scan, no point measured")
                else:
                    expect(info["points"] == j["progress"]["done"] and info["outcome"] == "failed"
                           and info["reason"] and info["reason"] in reason,
                           f"{what}: the scan holds the {j['progress']['done']} measured points and the "
                           f"reason ({info['points']}, {info['outcome']}, {info['reason']})")
                fig["faults"] += 1
                fig["by_kind"][kind] += 1
            got = {}
            ev.sock.settimeout(10)
            while len(got) < len(plan):
                e = ev.next_event()
                if e["method"] == "instrument.fault":
                    got[e["params"]["instrument"]] = e["params"]["reason"]
            expect(all(got.get(n) == c.call("job.get", {"id": jobs[n]})["reason"] for n, _, _ in plan),
                   f"round {r}: an instrument.fault event for every fault ({len(got)})")
            j = c.call("job.get", {"id": healthy})
            while j["state"] in ("queued", "running") and time.time() < deadline:
                time.sleep(0.05)
                j = c.call("job.get", {"id": healthy})
            expect(j["state"] == "completed", f"round {r}: the healthy instrument's job completes ({j['state']})")
            again = c.call("job.submit", dict(SPEC, instrument="healthy"))["id"]
            while c.call("job.get", {"id": again})["state"] in ("queued", "running") and time.time() < deadline:
                time.sleep(0.05)
            expect(c.call("job.get", {"id": again})["state"] == "completed",
                   f"round {r}: after the faults the daemon still measures")
            status = c.call("daemon.status")
            expect(status["jobs"]["failed"] == len(plan), f"round {r}: daemon.status counts the failures")
            c.close()
            ev.close()
            expect(d.stop() == 0, f"round {r}: clean stop")
            answer, _ = store_check(d.state)
            expect(answer == "ok", f"round {r}: the store passes integrity_check ({answer})")
            fig["rounds"] += 1
        except Exception:
            print(d.log_text()[-8000:])
            raise
        finally:
            d.cleanup()
            for s in sims:
                s.close()
    print(json.dumps(fig, indent=1))
    if a.report:
        with open(a.report, "w") as f:
            json.dump(fig, f, indent=1)
    finish()


main()
