#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The CAN driver from the command line: asph drivers lists it with its
options, a configuration is checked against them, and a scan on a kernel
without CAN (or without the interface) fails with a reason and no file."""
import os
import sys
import tempfile

from asphtest import expect, finish, run, run_json

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

finish()
