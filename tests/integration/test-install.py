#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The programs carry their own files: installed into a staging DESTDIR
(meson install --destdir), as a package build does, asph finds its
built-in line profiles and asphd serves its web page, with no data files
installed for them and no setting pointing anywhere (the tests run the
build tree's programs the same way)."""
import json
import os
import shutil
import subprocess
import sys
import tempfile
import urllib.request

sys.path.insert(0, os.path.dirname(__file__))
import daemontest  # noqa: E402
from daemontest import Daemon, expect, finish, mock_instrument, web_port  # noqa: E402

BUILD = os.environ["ASPH_BUILD_ROOT"]
ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
MESON = os.environ.get("ASPH_MESON", "meson")
PREFIX = os.environ["ASPH_PREFIX"]

stage = tempfile.mkdtemp(prefix="asph-test-destdir-")
os.chmod(stage, 0o755)
try:
    p = subprocess.run([MESON, "install", "-C", BUILD, "--destdir", stage, "--no-rebuild", "--quiet"],
                       capture_output=True, text=True, timeout=300)
    expect(p.returncode == 0, f"meson install --destdir {stage} (exit {p.returncode}) {p.stderr[-300:]}")
    top = stage + PREFIX
    asph = os.path.join(top, os.environ["ASPH_BINDIR"], "asph")
    asphd = os.path.join(top, os.environ["ASPH_SBINDIR"], "asphd")
    expect(os.access(asph, os.X_OK) and os.access(asphd, os.X_OK), "asph and asphd are staged")
    datadir = os.path.join(top, os.environ["ASPH_DATADIR"], "asphd")
    expect(not os.path.exists(os.path.join(datadir, "web")) and
           not os.path.exists(os.path.join(datadir, "line-profiles")),
           "no web page or line profile is installed as files: they are compiled in")

    # as a user runs them: from another folder, no ASPH_* setting
    env = {k: v for k, v in os.environ.items() if not k.startswith("ASPH_LINE")}
    p = subprocess.run([asph, "drivers", "--json"], capture_output=True, text=True, cwd="/",
                       env=env, timeout=120)
    line = next((d for d in json.loads(p.stdout)["drivers"] if d["name"] == "line"), None) \
        if p.returncode == 0 else None
    sources = sorted(f[:-len(".profile")]
                     for f in os.listdir(os.path.join(ROOT, "drivers", "line", "profiles")))
    if line is not None:
        found = sorted(x["name"] for x in line["profiles"] if x["path"] == "built-in" and not x["error"])
        expect(found == sources, f"the staged asph has the built-in line profiles: {', '.join(found)}")
    else:
        expect(p.returncode == 0, f"the staged asph drivers --json (exit {p.returncode}) {p.stderr}")

    daemontest.ASPHD = asphd
    d = Daemon([mock_instrument()], extra={"http_listen": "127.0.0.1:0"})
    try:
        d.start()
        url = f"http://127.0.0.1:{web_port(d)}"
        for name in ("index.html", "app.js"):
            with urllib.request.urlopen(f"{url}/{name}", timeout=30) as r, \
                    open(os.path.join(ROOT, "daemon", "web", name), "rb") as f:
                expect(r.status == 200 and r.read() == f.read(),
                       f"the staged asphd, http_listen without http_root, serves {name}")
        expect(d.stop() == 0, "the staged asphd stops cleanly")
    except Exception:
        print(d.log_text())
        raise
    finally:
        d.cleanup()
finally:
    shutil.rmtree(stage, ignore_errors=True)
finish()
