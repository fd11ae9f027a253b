#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The CAN driver from the command line: asph drivers lists it with its
options, a configuration is checked against them, and a scan on a kernel
without CAN (or without the interface) fails with a reason and no file;
through can-sim-server, a streamed scan records the positions the drives'
touch probes latched, and falls back (interpolated or flagged) where a
drive has none."""
import json
import os
import re
import subprocess
import sys
import tempfile

from asphtest import ASPH, expect, finish, run, run_json

tmp = tempfile.TemporaryDirectory(prefix="asph-test-can-")
T = tmp.name

rc, out, _ = run("drivers")
if rc == 0 and "\ncan " not in out:
    print("the can driver is not built (-Ddrivers): skipped")
    sys.exit(77)
expect(rc == 0 and "x_counts_per_mm" in out and "homing_method" in out and "interface" in out,
       "asph drivers lists can with its options")
d = run_json("drivers", "--json")
can = next(x for x in d["drivers"] if x["name"] == "can")
opts = {o["name"]: o for o in can["options"]}
expect(set(can["roles"]) == {"stage", "probe"}, "can plays stage and probe")
expect(opts["x_node"]["type"] == "int" and opts["x_node"]["min"] == 0 and opts["x_node"]["max"] == 127
       and opts["x_node"]["help"], "node ids: int 0..127 with help")
expect(opts["interface"]["default"] == "can0" and opts["speed"]["unit"] == "mm/s",
       "interface default and units")
expect(opts["nmt_reset"]["choices"] == ["communication", "node", "none"], "nmt_reset choices")

base = ["scan", "strong", "--method", "fermat", "--points", "100", "--quiet"]
out_path = os.path.join(T, "x.asph")
rc, _, err = run(*base, "--instrument", "can:x_node=200", "-o", out_path)
expect(rc == 2 and "x_node" in err, "a node id out of range is refused naming the option")

conf = os.path.join(T, "bench.json")
with open(conf, "w") as f:
    f.write('{"instruments": [{"name": "bench",\n'
            '  "stage": {"driver": "can", "options": {"interface": "asphcan9", "z_node": 7}},\n'
            '  "probe": {"driver": "mock", "options": {"time_factor": 0}}}]}\n')
rc, _, err = run(*base, "--instrument", conf, "-o", out_path)
expect(rc == 1 and "asphcan9" in err
       and ("CAN is not supported by this kernel" in err or "no such CAN interface" in err),
       "a missing CAN kernel or interface is said so")
expect(not os.path.exists(out_path), "nothing is written when the instrument does not open")
for name in ("touch_probe", "trigger_node", "trigger_output"):
    expect(name in opts and opts[name]["help"], f"option {name} with help")
expect(opts["touch_probe"]["choices"] == ["auto", "on", "off"], "touch_probe choices")
expect(opts["bitrate"]["type"] == "int" and opts["bitrate"]["default"] == "500000"
       and opts["bitrate"]["unit"] == "bit/s", "bitrate: int, bit/s, 500000 by default")


def estimate(**options):
    """asph plan --estimate on CAN axes with these options: the seconds,
    the line printed (nothing is opened: the interface need not exist)."""
    path = os.path.join(T, "estimate.json")
    with open(path, "w") as f:
        json.dump({"instruments": [{"name": "bench",
                   "stage": {"driver": "can", "options": {"interface": "asphcan9", **options}},
                   "probe": {"driver": "mock", "options": {"time_factor": 0, "rate": 1000}}}]}, f)
    rc, out, err = run("plan", "strong", "--method", "fermat", "--points", "200",
                       "--estimate", path, "-o", os.path.join(T, "p.csv"), "-q", check=0)
    m = re.fullmatch(r"estimate: (\d+\.\d) s \((\d+) min (\d\d) s\) to measure 200 points on "
                     + re.escape(path) + "\n", out)
    expect(rc == 0 and m is not None,
           f"asph plan --estimate predicts CAN axes without opening them ({out!r}, {err.strip()!r})")
    return float(m.group(1)) if m else 0.0, out


slow, line = estimate(speed=10, acceleration=10000)
fast, _ = estimate(speed=100, acceleration=10000)
expect(0 < fast < slow, f"faster axes, a shorter prediction ({fast} s < {slow} s)")
# the axes stop where they turn: a gentler acceleration costs time
soft, _ = estimate(speed=100, acceleration=100)
expect(soft > fast, f"a gentler acceleration, a longer prediction ({soft} s > {fast} s)")
# at 100 mm/s the points come faster than the bus feeds them: the bus sets
# the pace, a slower bus a longer measuring time
slow_bus, _ = estimate(speed=100, acceleration=10000, bitrate=125000)
expect(slow_bus > 1.5 * fast, f"a 125 kbit/s bus, a longer prediction ({slow_bus} s, {fast} s)")


def can_sim_server():
    """tests/drivers/can-sim-server of the same build (ASPH_CAN_SIM, else
    beside the asph binary's build directory)."""
    if os.environ.get("ASPH_CAN_SIM"):
        return os.environ["ASPH_CAN_SIM"]
    d = os.path.dirname(os.path.abspath(ASPH))
    for _ in range(3):
        d = os.path.dirname(d)
        path = os.path.join(d, "tests", "drivers", "can-sim-server")
        if os.access(path, os.X_OK):
            return path
    return None


POINTS = 30


def streamed_scan(sim_bin, tag, sim_args):
    """A streamed scan through can-sim-server: the scan's position sources
    and the trigger edges the drives saw."""
    sock = os.path.join(T, f"{tag}.sock")
    sim = subprocess.Popen([sim_bin, "--socket", sock, *sim_args], stdin=subprocess.PIPE,
                           stdout=subprocess.PIPE, text=True)
    try:
        expect(json.loads(sim.stdout.readline()).get("ready"), f"{tag}: can-sim-server listens")
        conf = os.path.join(T, f"{tag}.json")
        with open(conf, "w") as f:
            json.dump({"instruments": [{"name": "bench",
                       "stage": {"driver": "can", "options": {
                           "interface": f"unix:{sock}", "heartbeat": 20, "heartbeat_timeout": 2000,
                           "sdo_timeout": 1000, "speed": 100}},
                       "probe": {"driver": "mock", "options": {"time_factor": 0}}}]}, f)
        scan = os.path.join(T, f"{tag}.asph")
        rc, _, err = run("scan", "strong", "--method", "fermat", "--points", str(POINTS), "--quiet",
                         "--instrument", conf, "-o", scan)
        expect(rc == 0, f"{tag}: a streamed scan on CAN axes completes ({err.strip()[:200]})")
        sim.stdin.write("status\n")
        sim.stdin.flush()
        status = json.loads(sim.stdout.readline())
        info = run_json("scaninfo", "--json", scan) if rc == 0 else {}
        return info, status
    finally:
        sim.stdin.close()
        sim.wait(timeout=60)


# Under valgrind each of these scans costs some 10 s more whatever its
# size (valgrind's start, the instrument's bring-up, scaninfo): they run
# plainly and under ASan+UBSan; test-can runs the same sweeps and a
# streamed scan through the executor under valgrind.
sim_bin = can_sim_server()
if os.environ.get("ASPH_UNDER_VALGRIND"):
    print("under valgrind: the streamed scans through can-sim-server are not run")
elif sim_bin:
    info, status = streamed_scan(sim_bin, "latched", [])
    sources = info.get("positions", {})
    expect(sources.get("latched") == POINTS and info.get("points") == POINTS,
           f"every point latched by the drives' touch probes ({sources})")
    expect(status["trigger_edges"] == 2 * POINTS, "one trigger pulse per point (rising and falling edge)")
    info, status = streamed_scan(sim_bin, "fallback", ["--touch-probe", "2:none"])
    sources = info.get("positions", {})
    expect(not sources.get("latched") and info.get("points") == POINTS
           and sources.get("interpolated", 0) + sources.get("commanded", 0) == POINTS,
           f"a drive without touch probe: nothing latched, each point interpolated or "
           f"flagged commanded ({sources})")
else:
    print("no can-sim-server in this build: the streamed scans are not run")

finish()
