#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Runs one libFuzzer target as a test: its seed corpus, then
ASPH_FUZZ_SECONDS of fuzzing (default 10; 0 replays the corpus only).

usage: run-fuzz.py BINARY SEED_DIR WORK_DIR

New inputs the fuzzer finds go to WORK_DIR/corpus (never the source tree);
a crash is saved under WORK_DIR/ and fails the test with its path. libFuzzer
exits 77 when it finds one (its -error_exitcode), which meson would count
as a skip: any failure of the fuzzer is exit 1 here. UBSan stops at its
first report, as in scripts/test and scripts/fuzz, so that undefined
behaviour is a crash and not a line in the log.
"""
import os
import subprocess
import sys


def main():
    binary, seeds, work = sys.argv[1:4]
    seconds = int(os.environ.get("ASPH_FUZZ_SECONDS", "10"))
    corpus = os.path.join(work, "corpus")
    os.makedirs(corpus, exist_ok=True)
    args = [binary, "-timeout=10", "-rss_limit_mb=2048", "-max_len=65536",
            "-print_final_stats=1", "-artifact_prefix=" + work + "/"]
    if seconds > 0:
        args += ["-max_total_time=%d" % seconds, corpus, seeds]
    else:
        args += ["-runs=0", seeds]
    env = dict(os.environ)
    env.setdefault("ASAN_OPTIONS", "detect_leaks=1:abort_on_error=1")
    env.setdefault("UBSAN_OPTIONS", "halt_on_error=1:print_stacktrace=1")
    before = set(os.listdir(work))
    r = subprocess.run(args, env=env)
    if r.returncode != 0:
        found = sorted(f for f in set(os.listdir(work)) - before
                       if f.startswith(("crash-", "timeout-", "oom-", "leak-", "slow-unit-")))
        print("fuzz target failed (exit %d); the input is in %s/: %s"
              % (r.returncode, work, " ".join(found) or "none written"), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
