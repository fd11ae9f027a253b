#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Runs one libFuzzer target as a test: its seed corpus, then
ASPH_FUZZ_SECONDS of fuzzing (default 10; 0 replays the corpus only).

usage: run-fuzz.py BINARY SEED_DIR WORK_DIR

New inputs the fuzzer finds go to WORK_DIR/corpus (never the source tree);
a crash is saved under WORK_DIR/ and fails the test with its path.
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
    r = subprocess.run(args, env=env)
    if r.returncode != 0:
        print("fuzz target failed; the input is in %s/" % work, file=sys.stderr)
    return r.returncode


if __name__ == "__main__":
    sys.exit(main())
