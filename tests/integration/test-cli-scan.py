#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph drivers, asph scan (with the mock and replay instruments, faults,
limits, a SIGKILL half-way) and asph replay."""
import json
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time

from asphtest import ASPH, expect, finish, run, run_json

tmp = tempfile.TemporaryDirectory(prefix="asph-test-scan-")
T = tmp.name


def path(name):
    return os.path.join(T, name)


def scaninfo(scan):
    return run_json("scaninfo", "--json", scan)


# --- asph drivers -----------------------------------------------------------
rc, out, _ = run("drivers")
if rc == 0 and not ("\nmock " in out and "\nreplay " in out):
    print("the mock and replay drivers are not built (-Ddrivers): skipped")
    sys.exit(77)
expect(rc == 0 and "mock" in out and "replay" in out and "fail_after" in out,
       "asph drivers lists mock and replay with their options")
d = run_json("drivers", "--json")
mock = next(x for x in d["drivers"] if x["name"] == "mock")
rate = next(o for o in mock["options"] if o["name"] == "rate")
expect(d["driver_abi"] >= 1 and set(mock["roles"]) == {"stage", "probe"},
       "drivers --json: ABI version and roles")
expect(rate["type"] == "double" and rate["default"] == "1000" and rate["unit"] == "Hz"
       and rate["min"] > 0 and rate["help"], "drivers --json: an option's type, default, range, help")
probe = next(o for o in mock["options"] if o["name"] == "probe")
expect(probe["type"] == "enum" and probe["choices"] == ["optical", "tactile"], "enum choices")

# --- refusals at configuration time ----------------------------------------
base = ["scan", "strong", "--method", "fermat", "--points", "400", "--quiet"]
rc, _, err = run(*base, "--instrument", "mock:rate=fast", "-o", path("x.asph"))
expect(rc == 2 and "rate" in err and "number" in err, "a wrong type is refused naming the option")
rc, _, err = run(*base, "--instrument", "mock:bogus=1", "-o", path("x.asph"))
expect(rc == 2 and "bogus" in err, "an unknown option is refused naming it")
rc, _, err = run(*base, "--instrument", "mock:speed=-1", "-o", path("x.asph"))
expect(rc == 2 and "speed" in err and "outside" in err, "an out-of-range value is refused")
rc, _, err = run(*base, "--instrument", "nosuch", "-o", path("x.asph"))
expect(rc == 2 and "nosuch" in err, "an unknown driver is refused")
expect(not os.path.exists(path("x.asph")), "nothing was written for a refused instrument")

conf = path("bench.json")
with open(conf, "w") as f:
    f.write('{"instruments": [\n'
            '  {"name": "a", "stage": {"driver": "mock", "options": {"time_factor": 0}},\n'
            '   "probe": {"driver": "mock", "options": {"time_factor": 0, "rate": "x"}}}]}\n')
rc, _, err = run(*base, "--instrument", conf, "-o", path("x.asph"))
expect(rc == 2 and f"{conf}:3:" in err and "rate" in err,
       "a configuration file's error has file, line and column")
with open(conf, "w") as f:
    f.write('{"instruments": [\n'
            '  {"name": "first", "stage": {"driver": "mock"}, "probe": {"driver": "mock"}},\n'
            '  {"name": "fast", "stage": {"driver": "mock", "options": {"time_factor": 0}},\n'
            '   "probe": {"driver": "mock", "options": {"time_factor": 0, "probe": "tactile"}}}]}\n')
rc, _, err = run(*base, "--instrument", conf + "#fast", "-o", path("conf.asph"))
info = scaninfo(path("conf.asph"))
expect(rc == 0 and info["points"] == 400 and info["instrument"]["name"] == "fast"
       and info["flags"]["tip-compensated"] == 400, "FILE#NAME picks an instrument of the file")

# --- a scan, faults, limits ------------------------------------------------
good = path("good.asph")
rc, out, err = run(*base, "--instrument", "mock:time_factor=0,tilt_x=120,form=5:30", "-o", good)
info = scaninfo(good)
expect(rc == 0 and info["outcome"] == "completed" and info["points"] == 400,
       "asph scan measures every plan point")
rc, _, err = run(*base, "--instrument", "mock:time_factor=0", "-o", good)
expect(rc == 1 and "exists" in err.lower(), "an existing scan is not overwritten without --force")

for spec, words in (("fail_after=150", "disconnected"), ("timeout_at=150", "did not answer"),
                    ("out_of_range_at=151", "out of range")):
    scan = path(spec.split("=")[0] + ".asph")
    # faults by reading number: without drift references in between
    rc, _, err = run(*base, "--instrument", "mock:time_factor=0,drift_interval=off," + spec,
                     "-o", scan)
    info = scaninfo(scan)
    expect(rc == 1 and words in err and info["outcome"] == "failed" and words in info["reason"]
           and 149 <= info["points"] <= 151, f"fault {spec}: clear reason, readable file")

rc, _, err = run(*base, "--instrument", "mock:time_factor=0,travel_xy=10", "-o", path("lim.asph"))
info = scaninfo(path("lim.asph"))
expect(rc == 1 and "outside its travel" in err and info["points"] == 0,
       "a plan outside the travel is refused before anything moves")

# --- the mock's part is the lens being measured -----------------------------
tp = ["scan", "turning-point", "--method", "fermat", "--points", "200", "--quiet"]
rc, _, err = run(*tp, "--instrument", "mock:time_factor=0", "-o", path("tp.asph"))
expect(rc == 0 and scaninfo(path("tp.asph"))["points"] == 200,
       "the mock measures the lens of the scan (turning-point) by default")
rc, _, err = run(*tp, "--instrument", "mock:time_factor=0,lens=strong", "-o", path("wrong.asph"))
expect(rc != 0 and "out of range" in err and scaninfo(path("wrong.asph"))["outcome"] == "failed",
       "lens= still puts a different part on the machine")

# --- SIGKILL half-way: the reader recovers what was flushed -----------------
def first_block_written(scan):
    """Whether the scan file holds a whole block of points after its header
    (docs/scan-format.md: a 20-byte prefix with the header's length at
    offset 12, the header, then blocks that start with "ASPB", their type
    (1: points) and their payload's length at offset 28, followed by the
    payload and a 4-byte checksum). A block whose end is not yet on disk
    does not count: the kill could land inside it and leave nothing."""
    try:
        with open(scan, "rb") as f:
            prefix = f.read(20)
            if len(prefix) < 20:
                return False
            f.seek(20 + struct.unpack_from("<I", prefix, 12)[0])
            while True:
                head = f.read(32)
                if len(head) < 32 or head[:4] != b"ASPB":
                    return False
                rest = struct.unpack_from("<I", head, 28)[0] + 4
                if struct.unpack_from("<H", head, 4)[0] == 1:
                    return len(f.read(rest)) == rest
                f.seek(rest, 1)
    except OSError:
        return False


# The kill comes once the first block of points is on disk: the mock paces
# its 150,000 readings in real time (3.75 s at 40 kHz), so the scan is then
# still running at any speed of the machine (under valgrind too).
killed = path("killed.asph")
p = subprocess.Popen([ASPH, "scan", "strong", "--method", "fermat", "--points", "150000",
                      "--instrument", "mock:rate=40000,speed=10000", "-o", killed, "--quiet"],
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
while not first_block_written(killed) and p.poll() is None:
    time.sleep(0.01)
p.send_signal(signal.SIGKILL)
p.wait()
info = scaninfo(killed)
n = info["points"]
expect(p.returncode == -signal.SIGKILL and not info["ended"] and n > 0
       and info["plan_index"]["min"] == 0 and info["plan_index"]["max"] == n - 1,
       f"SIGKILL half-way: {n} flushed points recovered, in order")
rc, _, _ = run("export", killed, "-o", path("killed.csv"))
with open(path("killed.csv")) as f:
    rows = sum(1 for line in f if line.strip() and line[0] not in "#xX")
expect(rc == 0 and rows == n, "the killed scan exports the points it kept")
rc, _, err = run(*base[:5], "150000", "--instrument", "mock:time_factor=0", "-o", killed,
                 "--resume", "--quiet")
info = scaninfo(killed)
expect(rc == 0 and info["outcome"] == "completed" and info["points"] == 150000
       and info["resumes"] == 1, "--resume finishes the killed scan")

# --- replay --------------------------------------------------------------
again = path("again.asph")
rc, _, err = run(*base, "--instrument", "replay:file=" + good, "-o", again)
run("export", good, "-o", path("good.csv"), check=0)
run("export", again, "-o", path("again.csv"), check=0)
with open(path("good.csv")) as a, open(path("again.csv")) as b:
    expect(rc == 0 and a.read() == b.read(), "the replay instrument measures the recording again, bit for bit")

rc, _, _ = run("fit", "--help")
if rc == 0:
    rc1, replay_out, err1 = run("replay", good, "--json")
    rc2, fit_out, err2 = run("fit", "strong", path("good.csv"), "--json")
    replayed = json.loads(replay_out) if rc1 == 0 else {}
    acq = replayed.pop("acquisition", None)
    expect(rc1 == 0 and rc2 == 0 and replayed == json.loads(fit_out) and acq
           and acq["positions"]["latched"] == replayed["n_points"] and acq["drift"]["rounds"] >= 2,
           "asph replay --json is asph fit --json on the exported points, with the acquisition")
    _, again_out, _ = run("replay", again, "--json")
    again_json = json.loads(again_out)
    again_acq = again_json.pop("acquisition")
    expect(again_json == replayed and again_acq["positions"] == acq["positions"]
           and again_acq["drift"]["max_nm"] == acq["drift"]["max_nm"],
           "replaying the re-measured recording gives the same result")
else:
    print("ok - # skip asph fit is not built")

finish()
