#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The Modbus driver from the command line: asph drivers lists it with its
options and the AZ profile's registers, a configuration is checked against
them, and a scan whose drives cannot be reached (nobody listening on
127.0.0.1, no serial port) fails with a reason and no file."""
import os
import socket
import sys
import tempfile

from asphtest import expect, finish, run, run_json

tmp = tempfile.TemporaryDirectory(prefix="asph-test-modbus-")
T = tmp.name

rc, out, _ = run("drivers")
if rc == 0 and "\nmodbus " not in out:
    print("the modbus driver is not built (-Ddrivers): skipped")
    sys.exit(77)
expect(rc == 0 and "slave_x" in out and "reg_data" in out and "valid_register" in out,
       "asph drivers lists modbus with its options")
d = run_json("drivers", "--json")
mb = next(x for x in d["drivers"] if x["name"] == "modbus")
opts = {o["name"]: o for o in mb["options"]}
expect(set(mb["roles"]) == {"stage", "probe"}, "modbus plays stage and probe")
expect(opts["transport"]["choices"] == ["tcp", "rtu"] and opts["parity"]["default"] == "even",
       "transport and parity choices")
expect(opts["reg_data"]["default"] == "88" and opts["reg_command"]["default"] == "124"
       and opts["reg_status"]["default"] == "126" and opts["reg_position"]["default"] == "288",
       "the AZ profile's registers (0x0058, 0x007C, 0x007E, 0x0120) as defaults")
expect(opts["slave_x"]["min"] == 1 and opts["slave_x"]["max"] == 247 and opts["slave_x"]["help"],
       "slave ids: 1..247 with help")

base = ["scan", "strong", "--method", "fermat", "--points", "100", "--quiet"]
out_path = os.path.join(T, "x.asph")
rc, _, err = run(*base, "--instrument", "modbus:parity=mark", "-o", out_path)
expect(rc == 2 and "parity" in err, "a parity that does not exist is refused naming the option")
rc, _, err = run(*base, "--instrument", "modbus:slave_y=248", "-o", out_path)
expect(rc == 2 and "slave_y" in err, "a slave id out of range is refused naming the option")

# a port of 127.0.0.1 that nobody listens on
s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
s.bind(("127.0.0.1", 0))
port = s.getsockname()[1]
s.close()
rc, _, err = run(*base, "--instrument", "modbus:port=%d,timeout=50" % port, "-o", out_path)
expect(rc == 1 and ("127.0.0.1:%d: cannot connect" % port) in err,
       "nobody at the TCP port is said so")
expect(not os.path.exists(out_path), "nothing is written when the instrument does not open")

conf = os.path.join(T, "bench.json")
with open(conf, "w") as f:
    f.write('{"instruments": [{"name": "bench",\n'
            '  "stage": {"driver": "modbus", "options": {"transport": "rtu",\n'
            '    "device": "/dev/ttyUSB-asph-test-absent", "baud": 19200}},\n'
            '  "probe": {"driver": "mock", "options": {"time_factor": 0}}}]}\n')
rc, _, err = run(*base, "--instrument", conf, "-o", out_path)
expect(rc == 1 and "/dev/ttyUSB-asph-test-absent: no such serial port" in err,
       "a missing serial port is said so")
expect(not os.path.exists(out_path), "nothing is written when the instrument does not open")

finish()
