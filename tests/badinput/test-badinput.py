#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Feeds every case of the bad-input corpus (cases.py) to the command that
reads that kind of file and checks the answer:

  kind          command                                  documented answer
  prescription  asph lens show FILE                      exit 1
  lens-zmx      asph lens import FILE --surface 1        exit 1
  points-*      asph fit strong FILE                     exit 1
  instrument    asph scan ... --instrument FILE          exit 2 (docs/scanning.md)
  daemon        asphd --check-config --config FILE       exit 3 (docs/daemon.md)
  scan          asph scaninfo FILE                       exit 1, or exit 0 with
                                                         the damage in Recovery

Every refusal names the file, and for text formats where in it: line and
column, or the field. No case may crash (signal, sanitizer report) or hang
(60 s; 300 s under valgrind). Exit 0 when all cases pass, 1 otherwise; 77
without the binaries.

  test-badinput.py              run the corpus
  test-badinput.py --write DIR  write the cases as files, run nothing
  test-badinput.py --list       count the cases per kind
"""
import os
import re
import subprocess
import sys
import tempfile
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cases as corpus  # noqa: E402

ASPH = os.environ.get("ASPH_BIN")
ASPHD = os.environ.get("ASPHD_BIN")
# No case may hang; under valgrind (ASPH_UNDER_VALGRIND) the largest cases
# take a minute of their own.
TIMEOUT = 300 if os.environ.get("ASPH_UNDER_VALGRIND") else 60
# Under valgrind, one case in three of each kind (the first, the fourth...,
# generated large files among them). The plain and ASan+UBSan runs take
# every case; memcheck adds the uninitialised reads of the same code paths,
# and the whole corpus under it took 12 of the suite's 40 minutes.
SAMPLE = 3 if os.environ.get("ASPH_UNDER_VALGRIND") else 1

EXT = {"prescription": ".json", "lens-zmx": ".zmx", "points-csv": ".csv", "points-ply": ".ply", "points-json": ".json",
       "points-x3p": ".x3p", "points-sdf": ".sdf", "points-metropro": ".dat", "points-datx": ".datx",
       "instrument": ".json", "daemon": ".json", "scan": ".scan"}
EXIT = {"prescription": 1, "lens-zmx": 1, "points-csv": 1, "points-ply": 1, "points-json": 1,
        "points-x3p": 1, "points-sdf": 1, "points-metropro": 1, "points-datx": 1,
        "instrument": 2, "daemon": 3, "scan": 1}
# Refusals of a whole file have no line or field to name: the file is named.
WHOLE_FILE = re.compile(r"empty|too large|larger than|cannot read|binary data|no 'ply' magic|"
                        r"missing member|lack x, y or z|"
                        r"without end_header|faces before vertices|PLY data ends|more than the|"
                        r"only triangles|out of range|expected an array \"points\"|"
                        r"not a finite number|must be a JSON object|end of file expected|"
                        r"no SURF block|odd number of bytes|contains NUL bytes|invalid UTF-16")
MAP_FORMATS = ("points-x3p", "points-sdf", "points-metropro", "points-datx")
SANITIZER = re.compile(r"Sanitizer|runtime error:")


def command(kind, path, work):
    if kind == "prescription":
        return [ASPH, "lens", "show", path]
    if kind == "lens-zmx":
        return [ASPH, "lens", "import", path, "--surface", "1"]
    if kind.startswith("points-"):
        return [ASPH, "fit", "strong", path]
    if kind == "instrument":
        return [ASPH, "scan", "strong", "--method", "ci", "--points", "12", "--quiet",
                "--instrument", path, "-o", os.path.join(work, os.path.basename(path) + ".out")]
    if kind == "daemon":
        return [ASPHD, "--check-config", "--config", path]
    return [ASPH, "scaninfo", path]


def normalize(text):
    return text.replace("[", "").replace("]", "")


def judge(case, path, rc, out, err):
    """None if the answer is the documented one, else why not."""
    if rc < 0:
        return "killed by signal %d" % -rc
    if SANITIZER.search(err):
        return "sanitizer report:\n" + err[-3000:]
    if case.kind == "scan" and rc == 0:
        # A cut at a block boundary leaves a valid scan that ends early:
        # it says so ("unfinished"); any other damage stops the reading.
        m = re.search(r"^Recovery .*\((torn|checksum|corrupt): .*offset \d+", out, re.M) or \
            re.search(r"^Outcome +unfinished", out, re.M)
        return None if m else "damage not reported:\n" + out[-1500:]
    # A flipped bit where nothing checks it (a comment, a factor) leaves a
    # file that reads: the fit then takes or refuses its points.
    if case.kind in MAP_FORMATS and case.name.startswith("bit-flip") and rc in (0, 1):
        return None
    if rc != EXIT[case.kind]:
        return "exit %d, documented %d\n%s" % (rc, EXIT[case.kind], err[-1500:])
    if path not in err:
        return "the message does not name the file:\n" + err[-1500:]
    if case.field and normalize(case.field) + ":" not in normalize(err):
        return "the message does not name the field %s:\n%s" % (case.field, err[-1500:])
    if case.kind == "scan" or case.kind == "points-ply" and b"binary" in case.name.encode():
        return None
    # Binary maps and containers are located by a byte offset or an XML
    # element, or refused whole; the message names the format it found.
    if case.kind in MAP_FORMATS:
        return None if re.search(r"\b(x3p|sdf|metropro|datx|text|ply|json): ", err) else \
            "the message does not name the format:\n" + err[-1500:]
    located = re.search(re.escape(path) + r":\d+(:\d+)?: ", err) or \
        re.search(re.escape(path) + r"(:\d+)?: [\w.\[\]-]+: ", err)
    if not located and not WHOLE_FILE.search(err):
        return "the message says neither line and column nor field:\n" + err[-1500:]
    return None


def run_case(case, index, work):
    path = os.path.join(work, "%03d-%s%s" % (index, case.name, EXT[case.kind]))
    data = case.data() if callable(case.data) else case.data
    with open(path, "wb") as f:
        f.write(data)
    try:
        p = subprocess.run(command(case.kind, path, work), capture_output=True, timeout=TIMEOUT)
        why = judge(case, path, p.returncode, p.stdout.decode(errors="replace"),
                    p.stderr.decode(errors="replace"))
    except subprocess.TimeoutExpired:
        why = "no answer in %d s" % TIMEOUT
    os.unlink(path)
    return why


def write(cases, out):
    for i, c in enumerate(cases):
        d = os.path.join(out, c.kind)
        os.makedirs(d, exist_ok=True)
        with open(os.path.join(d, "%03d-%s%s" % (i, c.name, EXT[c.kind])), "wb") as f:
            f.write(c.data() if callable(c.data) else c.data)


def main():
    cases = corpus.all_cases()
    if sys.argv[1:2] == ["--list"]:
        for kind, n in Counter(c.kind for c in cases).items():
            print("%-13s %4d" % (kind, n))
        print("%-13s %4d" % ("total", len(cases)))
        return 0
    if sys.argv[1:2] == ["--write"]:
        write(cases, sys.argv[2])
        return 0
    if not ASPH or not ASPHD or not os.access(ASPH, os.X_OK) or not os.access(ASPHD, os.X_OK):
        print("ASPH_BIN and ASPHD_BIN must name the asph and asphd binaries")
        return 77
    if SAMPLE > 1:
        seen = Counter()
        sampled = []
        for c in cases:
            if seen[c.kind] % SAMPLE == 0:
                sampled.append(c)
            seen[c.kind] += 1
        print(f"under valgrind: {len(sampled)} of the {len(cases)} cases, one in {SAMPLE} of each kind")
        cases = sampled
    failed = Counter()
    # One case per core at a time. The generated cases (the files of
    # megabytes, up to 16 s each under valgrind) go first, so that no core
    # is left alone with one of them at the end; the answers are printed in
    # the corpus's order.
    order = sorted(range(len(cases)), key=lambda i: not callable(cases[i].data))
    with tempfile.TemporaryDirectory(prefix="asph-badinput-") as work:
        with ThreadPoolExecutor(max_workers=len(os.sched_getaffinity(0))) as pool:
            futures = {i: pool.submit(run_case, cases[i], i, work) for i in order}
            for i, case in enumerate(cases):
                why = futures[i].result()
                if why:
                    failed[case.kind] += 1
                    print("FAIL %s/%s: %s" % (case.kind, case.name, why.rstrip()))
    total = Counter(c.kind for c in cases)
    for kind in total:
        print("%-13s %4d cases, %d failed" % (kind, total[kind], failed[kind]))
    print("%d bad inputs, %d answered as documented" % (len(cases), len(cases) - sum(failed.values())))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
