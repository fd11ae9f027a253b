# SPDX-License-Identifier: GPL-3.0-or-later
"""ASPH_WRAPPER for the Python tests: the test setup 'valgrindpy'
(tests/meson.build) puts this folder on PYTHONPATH, so that python loads
it at start-up in every test script. Every asph, asphd and asphctl the
script launches through subprocess then runs as ASPH_WRAPPER (split like a
shell command line) followed by the original command.

When the wrapper is valgrind, each wrapped process writes its report to
its own log file (--log-file=DIR/PID.log, with --quiet: empty when
clean); at exit the script prints every non-empty report and exits 1, so
that an error or a leak in a process whose exit code the test does not
look at (a daemon killed on purpose, a client expected to fail) still
fails the test."""
import atexit
import glob
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile

_ARGS = shlex.split(os.environ.get("ASPH_WRAPPER", ""))
_NAMES = {"asph", "asphd", "asphctl"}
_PATHS = {os.path.realpath(os.environ[v]) for v in ("ASPH_BIN", "ASPHD_BIN", "ASPHCTL_BIN")
          if os.environ.get(v)}
_LOGDIR = None


def _ours(program):
    program = os.fspath(program)
    return os.path.basename(program) in _NAMES or os.path.realpath(program) in _PATHS


# valgrind 3.19 does not know openat2() (Linux 5.6, syscall 437): it says so
# in five lines and fails the call with ENOSYS, where lib/util/util-fs.c
# opens the same file with its O_NOFOLLOW walk. That notice is no error of
# the program's and is left out; anything else in a log fails the test.
_UNKNOWN_OPENAT2 = re.compile(
    r"--\d+-- WARNING: unhandled amd64-linux syscall: 437\n"
    r"(--\d+-- [^\n]*\n){4}")


def wrapped(args):
    """args as the wrapper runs them: for a command that starts ours
    through another (unshare, sh -c 'exec "$@"'), which Popen cannot see."""
    return [*_ARGS, *args] if _ARGS and args and _ours(args[0]) else list(args)


def report_text(log):
    """What a valgrind log says that is an error of the program's: its
    text without the openat2() notice, empty when clean or absent."""
    try:
        with open(log, errors="replace") as f:
            return _UNKNOWN_OPENAT2.sub("", f.read()).strip()
    except FileNotFoundError:
        return ""


def _report():
    bad = []
    for log in sorted(glob.glob(os.path.join(_LOGDIR, "*.log"))):
        text = report_text(log)
        if text:
            bad.append(text)
    shutil.rmtree(_LOGDIR, ignore_errors=True)
    if bad:
        sys.stdout.flush()
        print(f"not ok - {len(bad)} wrapped process(es) reported errors:", flush=True)
        for text in bad:
            print(text, flush=True)
        os._exit(1)


if _ARGS:
    if os.path.basename(_ARGS[0]) == "valgrind":
        _LOGDIR = tempfile.mkdtemp(prefix="asph-wrapper-")
        os.chmod(_LOGDIR, 0o1777)  # clients run under other uids too
        _ARGS.append(f"--log-file={_LOGDIR}/%p.log")
        atexit.register(_report)
    _popen_init = subprocess.Popen.__init__

    def _wrapped_init(self, args, *rest, **kw):
        if isinstance(args, (list, tuple)) and args and _ours(args[0]):
            args = [*_ARGS, *args]
        return _popen_init(self, args, *rest, **kw)

    subprocess.Popen.__init__ = _wrapped_init
