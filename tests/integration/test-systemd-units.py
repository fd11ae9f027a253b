#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""systemd-analyze verify accepts asphd.service and asphd.socket, and the
service's exposure score (systemd-analyze security --offline) is the one
docs/daemon.md records, and at most 2.0. The unit keeps the state private
(UMask=0027, StateDirectoryMode=0750), bounds memory and descriptors
(MemoryMax=, LimitNOFILE= with room for limits.max_clients), reaches only
the loopback unless a drop-in says more, and no longer gives the daemon
every serial port (no SupplementaryGroups=dialout); the drop-in example
for other hosts is a valid one."""
import os
import re
import shutil
import subprocess
import sys
import tempfile

from daemontest import ASPHD, expect, finish

analyze = shutil.which("systemd-analyze")
if not analyze:
    print("SKIP: systemd-analyze is not installed")
    sys.exit(77)
ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
service = os.environ["ASPHD_SERVICE"]

with tempfile.TemporaryDirectory() as tmp:
    # The unit as installed, with ExecStart pointing at the binary just built.
    with open(service) as f:
        text = f.read()
    text = re.sub(r"^ExecStart=.*$", f"ExecStart={os.path.abspath(ASPHD)}", text, flags=re.M)
    unit = os.path.join(tmp, "asphd.service")
    with open(unit, "w") as f:
        f.write(text)
    shutil.copy(os.path.join(ROOT, "systemd", "asphd.socket"), tmp)
    p = subprocess.run([analyze, "verify", "--man=no", unit, os.path.join(tmp, "asphd.socket")],
                       capture_output=True, text=True)
    expect(p.returncode == 0 and not p.stderr.strip(), f"systemd-analyze verify: clean {p.stderr.strip()}")
    for key in ("Type=notify", "WatchdogSec=", "StateDirectory=asphd", "RuntimeDirectory=asphd",
                "ConfigurationDirectory=asphd", "ProtectSystem=strict", "ProtectHome=yes",
                "PrivateTmp=yes", "NoNewPrivileges=yes", "DevicePolicy=closed",
                "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_CAN AF_NETLINK",
                "UMask=0027", "StateDirectoryMode=0750", "MemoryMax=", "MemoryHigh=",
                "IPAddressDeny=any", "IPAddressAllow=localhost"):
        expect(re.search(rf"^{re.escape(key)}", text, re.M), f"the service sets {key}")
    expect(not re.search(r"^SupplementaryGroups=.*dialout", text, re.M),
           "the service does not give the daemon every serial port (dialout)")
    m = re.search(r"^LimitNOFILE=(\d+)$", text, re.M)
    expect(m and int(m.group(1)) >= 256 + 64, f"LimitNOFILE= leaves room for 256 clients ({m and m.group(1)})")
    with open(os.path.join(ROOT, "systemd", "tmpfiles-asphd.conf")) as f:
        expect("d /var/lib/asphd 0750 " in f.read(), "tmpfiles makes the state directory 0750")
    # The drop-in for other hosts, on top of the unit.
    dropin = os.path.join(tmp, "asphd.service.d")
    os.mkdir(dropin)
    shutil.copy(os.path.join(ROOT, "systemd", "network.conf.example"), os.path.join(dropin, "network.conf"))
    p = subprocess.run([analyze, "verify", "--man=no", unit, os.path.join(tmp, "asphd.socket")],
                       capture_output=True, text=True)
    expect(p.returncode == 0 and not p.stderr.strip(), f"with network.conf.example as a drop-in: clean {p.stderr.strip()}")
    shutil.rmtree(dropin)
    p = subprocess.run([analyze, "security", "--offline=true", "--no-pager", unit],
                       capture_output=True, text=True)
    m = re.search(r"Overall exposure level for asphd.service: ([0-9.]+)", p.stdout + p.stderr)
    if not m:
        print("SKIP: this systemd-analyze cannot score a unit file offline")
        sys.exit(77)
    score = float(m.group(1))
    expect(score <= 2.0, f"exposure {score} is at most 2.0")
    with open(os.path.join(ROOT, "docs", "daemon.md")) as f:
        doc = f.read()
    expect(f"exposure level {score}" in doc, f"docs/daemon.md records exposure level {score}")
finish()
