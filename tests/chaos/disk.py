#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Full and read-only state directories. The state directory is a small
tmpfs (disk full) or a bind mount remounted read-only under the running
daemon (root ignores permission bits, a read-only mount it cannot). In
each case a job that needs the disk fails with the reason, what was
recorded before stays readable and unchanged (results, scans, the store),
the daemon keeps answering, and once there is room again it measures.
Needs root (mount); exits 77 otherwise.

The guard that keeps room on the disk (limits.min_free_disk_mb) is
checked on the same kind of tmpfs.

  disk.py [full] [guard] [read-only]"""
import hashlib
import os
import subprocess
import sys
import time

from chaoslib import scan_info, scan_points, store_check
from daemontest import Client, Daemon, RpcError, expect, finish, mock_instrument

if os.geteuid() != 0:
    print("SKIP: needs root to mount a tmpfs and a read-only bind mount")
    sys.exit(77)

SMALL = {"lens": "strong", "plan": {"method": "fermat", "points": 400}}
BIG = {"lens": "strong", "plan": {"method": "fermat", "points": 60000}}


def mount(*args):
    p = subprocess.run(["mount", *args], capture_output=True, text=True)
    return p.returncode == 0, p.stderr.strip()


def umount(path):
    subprocess.run(["umount", "-l", path], capture_output=True)


def digest(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def wait_final(c, job, timeout=120):
    deadline = time.time() + timeout
    while time.time() < deadline:
        j = c.call("job.get", {"id": job})
        if j["state"] not in ("queued", "running"):
            return j
        time.sleep(0.05)
    raise TimeoutError(f"job {job} did not end")


def recorded(c, d, job):
    """The files of a completed job and their digests."""
    res = c.call("job.result", {"id": job})
    return {f: digest(os.path.join(res["dir"], f)) for f in sorted(os.listdir(res["dir"]))}


def free_bytes(path):
    st = os.statvfs(path)
    return st.f_bavail * st.f_frsize


def fill(path, leave):
    """Fills the file system of path up to leave bytes free."""
    filler = os.path.join(path, "filler")
    with open(filler, "ab") as f:
        chunk = b"\0" * 65536
        while free_bytes(path) > leave + len(chunk):
            f.write(chunk)
            f.flush()
        while free_bytes(path) > leave:
            try:
                f.write(b"\0" * 4096)
                f.flush()
            except OSError:
                break
    return filler


def on_small_tmpfs(d):
    """A 24 MB tmpfs as d's state directory, or the test is skipped."""
    os.makedirs(d.state)
    ok, why = mount("-t", "tmpfs", "-o", "size=24m,mode=0755", "tmpfs", d.state)
    if not ok:
        print(f"SKIP: cannot mount a tmpfs: {why}")
        d.cleanup()
        sys.exit(77)


def disk_full():
    # "paced" measures at about 5,000 points a second, so that its scan
    # writes a block every second: some reach the disk before it is full.
    # The guard that keeps disk room (limits.min_free_disk_mb) is off
    # here: this case is about a disk that fills all the same.
    d = Daemon(instruments=[mock_instrument(time_factor=0), mock_instrument("paced", time_factor=0.004)],
               extra={"limits": {"min_free_disk_mb": 0}})
    on_small_tmpfs(d)
    try:
        d.start()
        c = Client(d.socket)
        first = c.call("job.submit", SMALL)["id"]
        expect(wait_final(c, first)["state"] == "completed", "disk full: a job completes before")
        before = recorded(c, d, first)

        # Leave 1000 kB: a block of 10,000 points (880 kB) fits, the big
        # job's scan (about 3 MB) cannot.
        filler = fill(d.state, 1000 * 1024)
        big = c.call("job.submit", dict(BIG, instrument="paced"))["id"]
        j = wait_final(c, big)
        expect(j["state"] == "failed" and "No space left on device" in (j["reason"] or ""),
               f"disk full: the job fails with the reason ({j['state']}: {j['reason']})")
        expect(c.call("daemon.status")["jobs"]["failed"] == 1, "disk full: the daemon answers and counts it")
        expect(recorded(c, d, first) == before, "disk full: the earlier job's files are unchanged")
        scan = os.path.join(d.state, "jobs", str(big), "scan.asphscan")
        info = scan_info(scan)
        expect(info is not None and 0 < info["points"] <= j["progress"]["done"],
               f"disk full: the blocks written before read back ({info and info['points']} points of "
               f"{j['progress']['done']} measured)")
        kept = scan_points(scan, os.path.join(d.top, "kept.csv"))

        # No room for anything: a submission is refused with a clear error or
        # fails with the reason; the daemon keeps answering.
        fill(d.state, 0)
        try:
            r = c.call("job.submit", SMALL)
            j = wait_final(c, r["id"])
            expect(j["state"] == "failed" and "No space left" in (j["reason"] or ""),
                   f"disk completely full: the job fails with the reason ({j['state']}: {j['reason']})")
        except RpcError as e:
            expect(e.code == 108 and "space" in str(e), f"disk completely full: submit refused ({e})")
        expect(c.call("daemon.status")["pid"] == d.proc.pid, "disk completely full: the daemon answers")

        os.unlink(filler)
        again = c.call("job.submit", SMALL)["id"]
        expect(wait_final(c, again)["state"] == "completed", "with room again the daemon measures")
        c.call("job.requeue", {"id": big})
        j = wait_final(c, big)
        expect(j["state"] == "completed", f"the failed job, re-queued, completes ({j['state']})")
        done = scan_points(scan, os.path.join(d.top, "done.csv"))
        expect(len(done) == BIG["plan"]["points"] and done[:len(kept)] == kept,
               f"it continued the recorded scan: the {len(kept)} points kept come first, unchanged")
        c.close()
        expect(d.stop() == 0, "disk full: clean stop")
        answer, _ = store_check(d.state)
        expect(answer == "ok", f"disk full: the store passes integrity_check ({answer})")
    except Exception:
        print(d.log_text()[-6000:])
        raise
    finally:
        if d.proc:
            d.stop()
        umount(d.state)
        d.cleanup()


def guard():
    """limits.min_free_disk_mb: on a 24 MB tmpfs keeping 8 MiB free, a job
    whose recording would not leave that is refused at submission (104,
    naming the limit), and one queued while there was room fails at its
    start with the same reason; nothing is lost and the daemon measures
    again once there is room."""
    d = Daemon(instruments=[mock_instrument(time_factor=0)], extra={"limits": {"min_free_disk_mb": 8}})
    on_small_tmpfs(d)
    try:
        d.start()
        c = Client(d.socket)
        first = c.call("job.submit", SMALL)["id"]
        expect(wait_final(c, first)["state"] == "completed", "guard: a job with room completes")
        # 100,000 points need about 16 MiB; 22 MiB are free, 8 are kept.
        code = c.call_error("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 100000}})
        expect(code == 104, f"guard: a recording that would eat into the kept room is refused (104: {code})")
        c.call("queue.stop")
        queued = c.call("job.submit", SMALL)["id"]
        filler = fill(d.state, 6 * 1024 * 1024)
        m = c.response(c.request("job.submit", SMALL))
        detail = m.get("error", {}).get("data", {}).get("detail", "")
        expect(m.get("error", {}).get("code") == 104 and "min_free_disk_mb" in detail,
               f"guard: with 6 MiB free even a small job is refused, naming the limit ({detail})")
        c.call("queue.start")
        j = wait_final(c, queued)
        expect(j["state"] == "failed" and "min_free_disk_mb" in (j["reason"] or ""),
               f"guard: the queued job fails at its start with the reason ({j['state']}: {j['reason']})")
        os.unlink(filler)
        c.call("job.requeue", {"id": queued})
        expect(wait_final(c, queued)["state"] == "completed", "guard: with room again, re-queued, it completes")
        c.close()
        expect(d.stop() == 0, "guard: clean stop")
    except Exception:
        print(d.log_text()[-6000:])
        raise
    finally:
        if d.proc:
            d.stop()
        umount(d.state)
        d.cleanup()


def read_only():
    """A mount with files open for writing cannot be remounted read-only,
    so the running daemon loses its jobs/ folder (a read-only bind mount
    over it, as after a file system error), and is then started on a
    read-only state directory."""
    d = Daemon(instruments=[mock_instrument(time_factor=0)])
    jobs = os.path.join(d.state, "jobs")
    mounted = []
    try:
        d.start()
        c = Client(d.socket)
        first = c.call("job.submit", SMALL)["id"]
        expect(wait_final(c, first)["state"] == "completed", "read-only: a job completes before")
        before = recorded(c, d, first)
        ok, why = mount("--bind", jobs, jobs)
        if not ok:
            print(f"SKIP: cannot bind-mount the jobs folder: {why}")
            sys.exit(77)
        mounted.append(jobs)
        ok, why = mount("-o", "remount,bind,ro", jobs)
        expect(ok, f"the jobs folder is remounted read-only ({why})")
        failed = None
        try:
            failed = c.call("job.submit", SMALL)["id"]
            j = wait_final(c, failed)
            expect(j["state"] == "failed" and "Read-only file system" in (j["reason"] or ""),
                   f"read-only: the job fails with the reason ({j['state']}: {j['reason']})")
        except RpcError as e:
            expect(e.code == 108 and "read-only" in str(e).lower(),
                   f"read-only: the submission is refused with the reason ({e})")
        expect(c.call("daemon.status")["pid"] == d.proc.pid, "read-only: the daemon answers")
        expect(c.call("job.get", {"id": first})["state"] == "completed", "read-only: earlier jobs read back")
        expect(recorded(c, d, first) == before, "read-only: the earlier job's files are unchanged")
        umount(jobs)
        mounted.remove(jobs)
        again = c.call("job.submit", SMALL)["id"]
        expect(wait_final(c, again)["state"] == "completed", "writable again: the daemon measures")
        if failed:
            c.call("job.requeue", {"id": failed})
            j = wait_final(c, failed)
            expect(j["state"] == "completed", f"the failed job, re-queued, completes ({j['state']})")
        c.close()
        expect(d.stop() == 0, "read-only: clean stop")

        answer, _ = store_check(d.state)
        expect(answer == "ok", f"read-only: the store passes integrity_check ({answer})")

        # Started on a read-only state directory, the daemon refuses to run
        # and says why.
        ok, why = mount("--bind", d.state, d.state)
        expect(ok, f"bind mount of the state directory ({why})")
        mounted.append(d.state)
        ok, why = mount("-o", "remount,bind,ro", d.state)
        expect(ok, f"the state directory is remounted read-only ({why})")
        p = subprocess.run([os.environ.get("ASPHD_BIN", "asphd"), "--config", d.config, "--socket",
                            d.socket, "--state-dir", d.state], capture_output=True, text=True, timeout=60)
        expect(p.returncode == 1 and "read-only" in p.stderr.lower(),
               f"asphd on a read-only state directory: exit 1 with the reason ({p.returncode}: "
               f"{p.stderr.strip()[-300:]})")
    except Exception:
        print(d.log_text()[-6000:])
        raise
    finally:
        if d.proc:
            d.stop()
        for m in reversed(mounted):
            umount(m)
        d.cleanup()


which = sys.argv[1:] or ["full", "guard", "read-only"]
if "full" in which:
    disk_full()
if "guard" in which:
    guard()
if "read-only" in which:
    read_only()
finish()
