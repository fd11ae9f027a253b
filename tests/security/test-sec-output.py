#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Low 14 of the security review: a label with terminal escape sequences,
sent by an operator, reaches other users' terminals through asphctl.

A label holding a clear-screen and cursor sequence, an OSC window title,
BEL, a newline, DEL, a C1 CSI (U+009B) and a right-to-left override
(U+202E) is submitted; asphctl list, status JOB, watch JOB, queue and
result, as another user, print none of those characters raw (they show as
\\x1b, \\n, \\u009b, ...), --json neither (as \\uNNNN escapes, still
valid JSON that reads back to the label), while job.get returns the label
exactly as sent. The failure reason of a job and an error's detail are
escaped the same way."""
import json
import re
import subprocess

from seclib import Accounts, expect, finish
from daemontest import ASPHCTL, Client, Daemon, mock_instrument

LABEL = "part\x1b[2J\x1b[H\x1b]0;owned\x07\nline2\x7f\u009b31m\u202eevil"
RAW = re.compile("[\x00-\x08\x0b-\x1f\x7f\u0080-\u009f\u202a-\u202e\u2066-\u2069]")

accounts = Accounts()
_, lab = accounts.group("lab")
reader = accounts.user("read", [lab])
d = Daemon(instruments=[mock_instrument(time_factor=0)], extra={"socket_group": lab})
try:
    d.start()
    c = Client(d.socket)
    job = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300},
                                "label": LABEL})["id"]
    deadline = 0
    while c.call("job.get", {"id": job})["state"] != "completed" and deadline < 600:
        deadline += 1
        __import__("time").sleep(0.05)
    expect(c.call("job.get", {"id": job})["label"] == LABEL, "the daemon keeps the label as sent")

    def as_reader(*args):
        p = reader.run([ASPHCTL, "--socket", d.socket, *map(str, args)], timeout=120)
        return p.returncode, p.stdout, p.stderr

    c.call("queue.stop")
    queued = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300},
                                   "label": LABEL})["id"]
    for args in (["list"], ["status", job], ["queue"], ["watch", job]):
        rc, out, err = as_reader(*args)
        bad = RAW.findall(out.replace("\n", "")) + RAW.findall(err.replace("\n", ""))
        shown = args[0] == "watch" or ("\\x1b[2J" in out and "\\u009b" in out and "\\u202e" in out
                                       and "\\nline2" in out)
        expect(rc == 0 and not bad and shown,
               f"asphctl {args[0]}: no raw control character ({len(bad)}), the label's shown as escapes")
    c.call("job.cancel", {"id": queued})
    rc, out, _ = as_reader("--json", "status", job)
    bad = RAW.findall(out.replace("\n", ""))
    back = json.loads(out)["label"] if rc == 0 else None
    expect(not bad and back == LABEL, f"--json: no raw control character, and it reads back to the label ({bad})")

    # A reason and an error detail carry other people's text too.
    rc, out, err = as_reader("cancel", job)
    expect(rc == 6 and not RAW.findall(err.replace("\n", "")), "an error's detail, escaped (permission denied: 6)")
    rc, out, err = as_reader("instruments", "no\x1b]0;t\x07such")
    expect(rc == 1 and "\x1b" not in err and "\\x1b" in err,
           f"a name echoed in an error comes back escaped ({err.strip()})")
    c.close()
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text()[-4000:])
    raise
finally:
    d.cleanup()
finish()
