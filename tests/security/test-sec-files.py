#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Medium 3, 4, 5 and Low 11, 12 of the security review: the daemon's
files are private and never written through a symlink.

- Private state (3): started with umask 0000 (as outside systemd), the
  state directory is 0750, job folders 0750, every file in them and the
  store 0640; a user with no access to the socket cannot read the store
  (where an inline prescription sits) nor a result, and a reader with
  access to the socket copies a result through it (asphctl result --out).
  A state directory an older install left 0755 is closed to others.
- Symlinks (4): a root-only file planted as the target of symlinks in a
  job's folder (result.json, residuals.csv, residual-map.png,
  scan.asphscan) and of a symlink put in place of the state directory by
  the user who owns its parent: the daemon, run as root, writes through
  none of them (the job completes, the links are replaced by files; the
  state directory in another user's hands is refused), and the file keeps
  its bytes. A resumed job whose scan is a symlink fails and says why.
- asphctl result --out (5): root copies a result into a folder where
  another user planted symlinks to a root-only file: the file is intact,
  the copies are the daemon's bytes.
- --socket (12): a regular file at the path is not removed; asphd refuses
  to start.
- Plugins (11): asphd --check-config with ASPH_DRIVER_PATH naming a folder
  others may write, holding a plugin whose constructor leaves a mark: the
  plugin is refused and none of its code ran."""
import glob
import hashlib
import json
import os
import stat
import subprocess
import time

from seclib import Accounts, expect, finish, tempdir
from daemontest import ASPHCTL, ASPHD, Client, Daemon, mock_instrument, poll_state

SPEC = {"lens": "strong", "plan": {"method": "fermat", "points": 300}}
INLINE = {"lens": {"type": "even_asphere", "name": "confidential-R20", "R": 20.097, "k": -1.0,
                   "A": {"4": -2.0868e-5, "6": -3.9031e-9}, "aperture_diameter": 20.0},
          "plan": {"method": "fermat", "points": 300}}
SECRET = b"root's own, must stay: " + os.urandom(8).hex().encode()


def mode(path):
    return stat.S_IMODE(os.lstat(path).st_mode)


def victim(directory):
    """A root-only file with known bytes."""
    path = os.path.join(directory, "root-only")
    with open(path, "wb") as f:
        f.write(SECRET)
    os.chmod(path, 0o600)
    return path


def intact(path):
    with open(path, "rb") as f:
        return f.read() == SECRET


def wait(c, job, states=("completed", "failed", "cancelled")):
    return poll_state(c, job, states)


def sha(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


accounts = Accounts()
_, lab = accounts.group("lab")
reader = accounts.user("read", [lab])
outsider = accounts.user("outs")          # no access to the socket
top = tempdir()
secret = victim(top)

# ------------------------------------------------------------ private state
d = Daemon(instruments=[mock_instrument(time_factor=0), mock_instrument("slow", time_factor=0.05)],
           extra={"socket_group": lab})
try:
    os.umask(0)
    d.start()
    os.umask(0o022)
    c = Client(d.socket)
    job = c.call("job.submit", INLINE)["id"]
    expect(wait(c, job)["state"] == "completed", "a job with an inline prescription completes")
    jobdir = os.path.join(d.state, "jobs", str(job))
    expect(mode(d.state) == 0o750, f"started with umask 0000: the state directory is 0750 ({oct(mode(d.state))})")
    expect(mode(os.path.join(d.state, "jobs")) == 0o750 and mode(jobdir) == 0o750,
           f"job folders 0750 ({oct(mode(jobdir))})")
    files = sorted(os.listdir(jobdir))
    modes = {f: oct(mode(os.path.join(jobdir, f))) for f in files}
    expect(len(files) >= 3 and all(m == "0o640" for m in modes.values()),
           f"every file of the job 0640 ({modes})")
    store = {f: oct(mode(f)) for f in glob.glob(os.path.join(d.state, "jobs.sqlite*"))}
    expect(store and all(m in ("0o640", "0o600") for m in store.values()), f"the store 0640 or stricter ({store})")
    probe = r'''
import json, sys
out = {}
for p in sys.argv[1:]:
    try:
        open(p, "rb").read(16)
        out[p] = "read"
    except OSError as e:
        out[p] = e.strerror
print(json.dumps(out))
'''
    seen = outsider.python(probe, os.path.join(d.state, "jobs.sqlite"),
                           os.path.join(jobdir, "result.json"), os.path.join(jobdir, "scan.asphscan"))
    expect(all(v == "Permission denied" for v in seen.values()),
           f"a user without the socket reads neither the store nor a result ({seen})")
    out = os.path.join(top, "copy")
    os.mkdir(out)
    os.chown(out, reader.uid, reader.gid)
    p = reader.run([ASPHCTL, "--socket", d.socket, "result", str(job), "--out", out])
    copied = sorted(os.listdir(out))
    expect(p.returncode == 0 and copied == sorted(x for x in files if not x.startswith(".")),
           f"a reader copies the result through the socket ({copied}; {p.stderr.strip()})")
    expect(all(sha(os.path.join(out, f)) == sha(os.path.join(jobdir, f)) for f in copied),
           "byte for byte")
    c.close()
    expect(d.stop() == 0, "clean stop")
    # An older install's open state directory.
    os.chmod(d.state, 0o755)
    d.start()
    expect(mode(d.state) == 0o750, f"a state directory left 0755 is closed to others ({oct(mode(d.state))})")
    expect("was open to other users" in d.log_text(), "and the log says so")

    # ------------------------------------------------- symlinks in a job's folder
    c = Client(d.socket)
    c.call("queue.stop")
    nxt = c.call("job.submit", SPEC)["id"]
    planted = os.path.join(d.state, "jobs", str(nxt))
    os.makedirs(planted, mode=0o750)
    for name in ("result.json", "residuals.csv", "residual-map.png", "scan.asphscan",
                 ".result.json.tmp"):
        os.symlink(secret, os.path.join(planted, name))
    c.call("queue.start")
    j = wait(c, nxt)
    expect(j["state"] == "completed", f"a job whose folder holds planted symlinks completes ({j['reason']})")
    expect(intact(secret), "the root-only file they point at keeps its bytes")
    kinds = {n: stat.S_ISREG(os.lstat(os.path.join(planted, n)).st_mode)
             for n in ("result.json", "residuals.csv", "residual-map.png", "scan.asphscan")}
    expect(all(kinds.values()), f"the links were replaced by the job's files ({kinds})")

    # A resumed job whose recording is a symlink fails and says why.
    r = c.call("job.submit", dict(SPEC, instrument="slow", plan={"method": "fermat", "points": 20000}))["id"]
    deadline = time.time() + 120
    while c.call("job.get", {"id": r})["progress"]["done"] == 0 and time.time() < deadline:
        time.sleep(0.05)
    c.call("queue.stop", {"abort": True})
    expect(wait(c, r, ("interrupted",))["resumable"], "a job stopped mid-scan is resumable")
    scan = os.path.join(d.state, "jobs", str(r), "scan.asphscan")
    os.unlink(scan)
    os.symlink(secret, scan)
    c.call("job.resume", {"id": r})
    c.call("queue.start")
    j = wait(c, r)
    expect(j["state"] == "failed" and "not a regular file" in (j["reason"] or ""),
           f"resumed, with its scan a symlink, it fails with the reason ({j['state']}: {j['reason']})")
    expect(intact(secret), "and the file is untouched")

    # ---------------------------------------------- asphctl result --out
    shared = os.path.join(top, "shared")
    os.mkdir(shared)
    os.chown(shared, outsider.uid, outsider.gid)
    for name in ("result.json", "residuals.csv", "scan.asphscan", "residual-map.png"):
        outsider.run(["/bin/ln", "-s", secret, os.path.join(shared, name)])
    expect(os.path.islink(os.path.join(shared, "result.json")), "another user planted symlinks in the folder")
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "result", str(nxt), "--out", shared],
                       capture_output=True, text=True, timeout=120)
    expect(p.returncode == 0, f"root copies a result into it ({p.stderr.strip()})")
    expect(intact(secret), "the root-only file the links named keeps its bytes")
    same = all(not os.path.islink(os.path.join(shared, n)) and
               sha(os.path.join(shared, n)) == sha(os.path.join(planted, n))
               for n in ("result.json", "residuals.csv", "scan.asphscan"))
    expect(same, "the copies are the daemon's bytes, in place of the links")
    c.close()
    expect(d.stop() == 0, "clean stop")

    # ------------------------------------ the state directory in other hands
    parent = os.path.join(top, "theirs")
    os.mkdir(parent)
    os.chown(parent, outsider.uid, outsider.gid)
    os.chmod(parent, 0o755)
    outsider.run(["/bin/ln", "-s", top, os.path.join(parent, "state")])
    cfg = os.path.join(top, "plain.conf")
    json.dump({"instruments": [mock_instrument()]}, open(cfg, "w"))
    p = subprocess.run([ASPHD, "--config", cfg, "--socket", os.path.join(top, "x.sock"),
                        "--state-dir", os.path.join(parent, "state")],
                       capture_output=True, text=True, timeout=60)
    expect(p.returncode == 1 and "belongs to another user" in p.stderr,
           f"a state directory whose parent another user owns (a symlink there): refused "
           f"({p.returncode}: {p.stderr.strip()[-160:]})")
    expect(not os.path.exists(os.path.join(top, "jobs.sqlite")) and intact(secret),
           "nothing was written where the link points")

    # ------------------------------------------------ --socket on a file
    regular = os.path.join(top, "not-a-socket")
    with open(regular, "wb") as f:
        f.write(SECRET)
    p = subprocess.run([ASPHD, "--config", cfg, "--socket", regular, "--state-dir", d.state],
                       capture_output=True, text=True, timeout=60)
    expect(p.returncode == 1 and "is not a socket" in p.stderr,
           f"--socket naming a regular file: refused ({p.returncode}: {p.stderr.strip()[-120:]})")
    with open(regular, "rb") as f:
        expect(f.read() == SECRET, "and the file is still there, unchanged")

    # ----------------------------------------------------------- plugins
    plugin = os.environ.get("ASPH_TEST_PLUGIN_GOOD")
    if plugin:
        pdir = os.path.join(top, "plugins")
        os.mkdir(pdir)
        os.chmod(pdir, 0o777)
        with open(plugin, "rb") as f, open(os.path.join(pdir, "echo.so"), "wb") as g:
            g.write(f.read())
        os.chmod(os.path.join(pdir, "echo.so"), 0o755)
        mark = os.path.join(top, "plugin-ran")
        env = dict(os.environ, ASPH_DRIVER_PATH=pdir, ASPH_TEST_PLUGIN_MARK=mark)
        p = subprocess.run([ASPHD, "--check-config", "--config", cfg], capture_output=True,
                           text=True, timeout=60, env=env)
        expect(not os.path.exists(mark) and "other users may write it" in p.stderr,
               f"--check-config with a plugin in a folder others may write: refused, none of "
               f"its code ran ({p.stderr.strip()[-160:]})")
        os.chmod(pdir, 0o755)
        p = subprocess.run([ASPHD, "--check-config", "--config", cfg], capture_output=True,
                           text=True, timeout=60, env=env)
        expect(os.path.exists(mark) and p.returncode == 0,
               "the same plugin in a trusted folder loads (its constructor ran)")
    else:
        print("# ASPH_TEST_PLUGIN_GOOD is not set: the plugin case is left out")
except Exception:
    print(d.log_text()[-4000:])
    raise
finally:
    d.cleanup()
finish()
