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

Then CAN_ROUNDS times the same with CAN stages: each instrument's stage is
three CiA 402 drives simulated by its own can-sim-server process (the can
driver's interface unix:PATH), its probe the mock. CAN_FAULTS of them fail
at a random frame (seeded): the gateway disconnects, the drives stall
(hear, never answer), answer garbage, or one drive faults. Besides the
checks above: the simulator must have seen the stage stopped (no drive
moving; every drive enabled when the fault came got a quick stop, or after
a disconnect reacted to the lost link), and once each simulator is healed
a further job on every instrument completes.

  faults.py [--rounds N] [--faults N] [--can-rounds N] [--can-faults N]
            [--can-sim PATH] [--seed S] [--report FILE]"""
import argparse
import json
import os
import random
import re
import shutil
import sys
import tempfile
import time

from chaoslib import CanSim, ModbusSensor, scan_info, store_check
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


# CAN: what each fault's reason must say (the drive fault's is built for
# its axis, node and code), and the reasons told apart for the figures.
CAN_POINTS = 120
CAN_KINDS = {
    "disconnect": r"unix:\S+: the device (closed the connection|went away)",
    "stall": r"(no answer to the SDO|heartbeat lost|sent no boot-up message)",
    "garbage": r"(no answer to the SDO|malformed SDO response|answered the SDO .* with a|bus-off|"
               r"error passive|heartbeat lost|sent no boot-up message)",
    "drive-fault": None,
}
CAN_REASONS = [("no SDO answer", r"no answer to the SDO"), ("heartbeat lost", r"heartbeat lost"),
               ("no boot-up", r"sent no boot-up"), ("malformed answer", r"malformed SDO response"),
               ("wrong kind of answer", r"answered the SDO"), ("bus-off", r"bus-off"),
               ("error passive", r"error passive"), ("link closed", r"the device (closed|went away)"),
               ("drive fault", r"drive fault")]
DRIVE_CODES = {0x7121: "motor blocked", 0x2310: "continuous over-current", 0x8611: "following error",
               0x4310: "excess temperature of the drive", 0x5441: "enable input inactive",
               0x7305: "incremental sensor fault"}
GARBAGE = ["length", "cob-id", "sdo-index", "sdo-command", "dlc", "error-frame", "mixed"]
AXES = {1: "x", 2: "y", 3: "z"}
SLOW = bool(os.environ.get("ASPH_UNDER_VALGRIND"))


def instrument(name, kind, at, seed, sims):
    if kind in MOCK:
        return mock_instrument(name, **{MOCK[kind]: at})
    sim = ModbusSensor(kind, at, seed)
    sims.append(sim)
    return {"name": name, "stage": {"driver": "mock", "options": {"time_factor": 0.02}},
            "probe": {"driver": "modbus", "options": {"transport": "tcp", "host": "127.0.0.1",
                                                      "port": sim.port, "timeout": 100, "retries": 1}}}


def can_instrument(name, path):
    # Timeouts for a shared, loaded machine (three processes take part in
    # each answer), wider under valgrind.
    stage = {"interface": f"unix:{path}", "heartbeat": 20, "heartbeat_timeout": 4000 if SLOW else 1000,
             "sdo_timeout": 2000 if SLOW else 500, "speed": 200, "acceleration": 5000}
    return {"name": name, "stage": {"driver": "can", "options": stage},
            "probe": {"driver": "mock", "options": {"time_factor": 0.02}}}


def wait_job(c, job, deadline):
    while time.time() < deadline:
        j = c.call("job.get", {"id": job})
        if j["state"] not in ("queued", "running"):
            return j
        time.sleep(0.05)
    return c.call("job.get", {"id": job})


def check_failed(c, d, job, name, what, pattern, deadline):
    """The checks every faulty job gets: failed with the reason, the
    instrument in fault, the scan holding the measured points."""
    j = wait_job(c, job, deadline)
    reason = j["reason"] or ""
    expect(j["state"] == "failed" and re.search(pattern, reason),
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
    return j


def fault_events(ev, c, jobs, what):
    got = {}
    ev.sock.settimeout(10)
    while len(got) < len(jobs):
        e = ev.next_event()
        if e["method"] == "instrument.fault":
            got[e["params"]["instrument"]] = e["params"]["reason"]
    expect(all(got.get(n) == c.call("job.get", {"id": job})["reason"] for n, job in jobs.items()),
           f"{what}: an instrument.fault event for every fault ({len(got)})")


def mock_round(r, rng, a, fig):
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
            check_failed(c, d, jobs[name], name, f"round {r}: {kind} at {at} on {name}", KINDS[kind],
                         deadline)
            fig["faults"] += 1
            fig["by_kind"][kind] += 1
        fault_events(ev, c, jobs, f"round {r}")
        j = wait_job(c, healthy, deadline)
        expect(j["state"] == "completed", f"round {r}: the healthy instrument's job completes ({j['state']})")
        again = c.call("job.submit", dict(SPEC, instrument="healthy"))["id"]
        expect(wait_job(c, again, deadline)["state"] == "completed",
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


# ---------------------------------------------------------------- CAN

CAN_SPEC = {"lens": "strong", "plan": {"method": "fermat", "points": CAN_POINTS}}


def stage_stopped(sim, kind, settle=5.0):
    """Whether the simulator saw the stage stopped: the fault came, no drive
    moves, and every drive enabled when it came got a quick stop or a
    disable operation (after a disconnect: reacted to the lost link).
    The daemon's last frames may still be on their way: polled a while."""
    deadline = time.time() + settle
    while True:
        st = sim.status()
        nodes = st["nodes"]
        ok = (st["fault"] == kind and all(not n["moving"] for n in nodes)
              and all(n["stops_since_fault"] >= 1 for n in nodes if n["enabled_at_fault"]))
        disconnect = kind == "disconnect"
        if disconnect:
            ok = ok and all(n["link_stops"] >= 1 for n in nodes if n["enabled_at_fault"])
        if ok or time.time() > deadline:
            return ok, st, disconnect


def can_calibrate(a, top):
    """Frames one job sends to its drives, for drawing the fault frames."""
    path = os.path.join(top, "calibrate.sock")
    sim = CanSim(a.can_sim, path, os.path.join(top, "calibrate.log"))
    d = Daemon(instruments=[can_instrument("can", path)])
    try:
        d.start()
        c = Client(d.socket)
        t0 = time.time()
        job = c.call("job.submit", dict(CAN_SPEC, instrument="can"))["id"]
        j = wait_job(c, job, time.time() + 300)
        seconds = time.time() - t0
        expect(j["state"] == "completed", f"CAN: a job through can-sim-server completes ({j['state']}: "
               f"{j['reason']})")
        frames = sim.status()["frames"]
        c.close()
        expect(d.stop() == 0, "CAN: clean stop after the calibration job")
    except Exception:
        print(d.log_text()[-8000:])
        raise
    finally:
        d.cleanup()
        rc = sim.close()
    expect(rc == 0, f"CAN: the simulator exits cleanly ({rc})")
    return frames, seconds


def can_round(r, rng, a, fig, frames, top):
    plan = []
    for i in range(a.can_faults):
        kind = rng.choice(list(CAN_KINDS))
        node = rng.choice(list(AXES))
        code = rng.choice(list(DRIVE_CODES))
        plan.append({"name": f"can{i}", "kind": kind, "at": rng.randint(1, int(0.85 * frames)),
                     "node": node, "code": code, "garbage": rng.choice(GARBAGE),
                     "seed": rng.randrange(1 << 30)})
    sims = {}
    healthy_path = os.path.join(top, f"r{r}-healthy.sock")
    t0 = time.time()
    try:
        sims["can-healthy"] = CanSim(a.can_sim, healthy_path, os.path.join(top, f"r{r}-healthy.log"))
        for p in plan:
            p["path"] = os.path.join(top, f"r{r}-{p['name']}.sock")
            sims[p["name"]] = CanSim(a.can_sim, p["path"], os.path.join(top, f"r{r}-{p['name']}.log"),
                                     fault=p["kind"], at=p["at"], node=p["node"], code=p["code"],
                                     garbage=p["garbage"], seed=p["seed"])
        insts = [can_instrument("can-healthy", healthy_path)]
        insts += [can_instrument(p["name"], p["path"]) for p in plan]
        d = Daemon(instruments=insts)
        try:
            can_round_jobs(r, d, sims, plan, fig)
        except Exception:
            print(d.log_text()[-8000:])
            raise
        finally:
            d.cleanup()
    finally:
        codes = {name: s.close() for name, s in sims.items()}
    expect(all(rc == 0 for rc in codes.values()), f"CAN round {r}: the simulators exit cleanly ({codes})")
    fig["can"]["seconds"].append(time.time() - t0)


def can_round_jobs(r, d, sims, plan, fig):
    f = fig["can"]
    d.start()
    c = Client(d.socket)
    ev = Client(d.socket)
    ev.call("events.subscribe", {"events": ["instrument"]})
    healthy = c.call("job.submit", dict(CAN_SPEC, instrument="can-healthy"))["id"]
    jobs = {p["name"]: c.call("job.submit", dict(CAN_SPEC, instrument=p["name"]))["id"] for p in plan}
    deadline = time.time() + 600
    for p in plan:
        kind, name = p["kind"], p["name"]
        what = f"CAN round {r}: {kind}" + (f" ({p['garbage']})" if kind == "garbage" else "") + \
            f" at frame {p['at']} on {name}"
        pattern = CAN_KINDS[kind]
        if kind == "drive-fault":
            pattern = re.escape(f"{AXES[p['node']]} (node {p['node']}): drive fault, error code "
                                f"0x{p['code']:04x} ({DRIVE_CODES[p['code']]})")
        j = check_failed(c, d, jobs[name], name, what, pattern, deadline)
        ok, st, disconnect = stage_stopped(sims[name], kind)
        enabled = sum(n["enabled_at_fault"] for n in st["nodes"])
        expect(ok, f"{what}: the stage was stopped: no drive moves, the {enabled} enabled at the fault "
               f"got " + ("their link-loss quick stop" if disconnect else "a quick stop") +
               f" ({[(n['node'], n['state'], n['moving'], n['stops_since_fault']) for n in st['nodes']]})")
        reason = j["reason"] or ""
        label = next((lab for lab, rx in CAN_REASONS if re.search(rx, reason)), "other")
        phase = "measuring" if j["progress"]["done"] > 0 else "before the first point"
        k = f["by_kind"].setdefault(kind, {"injected": 0, "as documented": 0, "stopped": 0,
                                           "reasons": {}, "phases": {}})
        k["injected"] += 1
        k["as documented"] += bool(j["state"] == "failed" and re.search(pattern, reason))
        k["stopped"] += ok
        k["reasons"][label] = k["reasons"].get(label, 0) + 1
        k["phases"][phase] = k["phases"].get(phase, 0) + 1
        f["moving_at_fault"] += any(n["moving_at_fault"] for n in st["nodes"])
        if kind == "garbage":
            f["garbage"][p["garbage"]] = f["garbage"].get(p["garbage"], 0) + 1
        f["faults"] += 1
    fault_events(ev, c, jobs, f"CAN round {r}")
    j = wait_job(c, healthy, deadline)
    expect(j["state"] == "completed",
           f"CAN round {r}: the healthy instrument's job completes ({j['state']}: {j['reason']}; "
           f"frames dropped by the simulator: {sims['can-healthy'].status()['dropped']})")
    # healed, every simulator serves a job again: the daemon keeps serving
    for p in plan:
        sims[p["name"]].heal()
    again = {p["name"]: c.call("job.submit", dict(CAN_SPEC, instrument=p["name"]))["id"] for p in plan}
    for name, job in again.items():
        j = wait_job(c, job, deadline)
        expect(j["state"] == "completed",
               f"CAN round {r}: once healed, {name} measures again ({j['state']}: {j['reason']}; "
               f"frames dropped by the simulator: {sims[name].status()['dropped']})")
        f["recovered"] += j["state"] == "completed"
    status = c.call("daemon.status")
    expect(status["jobs"]["failed"] == len(plan), f"CAN round {r}: daemon.status counts the failures")
    c.close()
    ev.close()
    expect(d.stop() == 0, f"CAN round {r}: clean stop")
    answer, _ = store_check(d.state)
    expect(answer == "ok", f"CAN round {r}: the store passes integrity_check ({answer})")
    f["rounds"] += 1


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--faults", type=int, default=6)
    ap.add_argument("--can-rounds", type=int, default=0)
    ap.add_argument("--can-faults", type=int, default=4)
    ap.add_argument("--can-sim", help="tests/drivers/can-sim-server (no CAN rounds without it)")
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--report")
    a = ap.parse_args()
    rng = random.Random(a.seed)
    fig = {"rounds": 0, "faults": 0, "by_kind": {k: 0 for k in KINDS}, "seed": a.seed}
    for r in range(a.rounds):
        mock_round(r, rng, a, fig)
    if a.can_rounds and not (a.can_sim and os.access(a.can_sim, os.X_OK)):
        print("no can-sim-server (the can driver is not built): no CAN rounds")
    elif a.can_rounds:
        fig["can"] = {"rounds": 0, "faults": 0, "recovered": 0, "moving_at_fault": 0, "by_kind": {},
                      "garbage": {}, "seconds": []}
        # socket paths must stay short (sun_path)
        top = tempfile.mkdtemp(prefix="asph-can-")
        try:
            frames, seconds = can_calibrate(a, top)
            fig["can"]["frames_per_job"] = frames
            fig["can"]["job_seconds"] = round(seconds, 2)
            for r in range(a.can_rounds):
                can_round(r, rng, a, fig, frames, top)
        finally:
            shutil.rmtree(top, ignore_errors=True)
        s = fig["can"].pop("seconds")
        fig["can"]["round_seconds"] = [round(min(s), 1), round(sum(s) / len(s), 1), round(max(s), 1)] if s else []
    print(json.dumps(fig, indent=1))
    if a.report:
        with open(a.report, "w") as f:
            json.dump(fig, f, indent=1)
    finish()


main()
