#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph drivers lists the line driver's profiles as a user finds them:
the built-in ones with no profile directory anywhere (they are compiled
in), a lab's own in a directory of $ASPH_LINE_PROFILE_PATH, one that
replaces a built-in of the same name, and one that does not load (with
its reason); a directory named there that is not one, or that the user
cannot read, is refused with the setting to change, and so is the lab's
profile directory (/etc/asphd/line-profiles from the package) when it is
not a directory the user can read."""
import os
import shutil
import subprocess
import sys
import tempfile

from asphtest import expect, finish, run, run_json

# the profiles' sources, to copy from: the programs never read them
SOURCES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "drivers", "line", "profiles")
os.environ.pop("ASPH_LINE_PROFILE_PATH", None)

d = run_json("drivers", "--json")
line = next((x for x in d["drivers"] if x["name"] == "line"), None)
if line is None:
    print("the line driver is not built (-Ddrivers): skipped")
    sys.exit(77)
built_ins = sorted(f[:-len(".profile")] for f in os.listdir(SOURCES) if f.endswith(".profile"))
profiles = {p["name"]: p for p in line["profiles"]}
expect(sorted(profiles) == built_ins and
       all(p["path"] == "built-in" and p["error"] is None and p["roles"] for p in profiles.values()),
       "with no profile directory, every file of drivers/line/profiles is built in: " + ", ".join(built_ins))

tmp = tempfile.TemporaryDirectory(prefix="asph-test-profiles-")
lab = tmp.name
# a lab's own gauge, a copy of the built-in Sylvac profile renamed
with open(os.path.join(SOURCES, "sylvac.profile")) as f:
    text = f.read()
with open(os.path.join(lab, "lab-gauge.profile"), "w") as f:
    f.write(text.replace("name sylvac", "name lab-gauge")
            .replace('description "Sylvac gauge (Opto RS232)"', 'description "our bench gauge"'))
# a lab's pi-gcs replaces the built-in one
shutil.copy(os.path.join(SOURCES, "pi-gcs.profile"), os.path.join(lab, "pi-gcs.profile"))
# one that does not load, and a file that is not a profile by its name
with open(os.path.join(lab, "broken.profile"), "w") as f:
    f.write("asphd-line-profile 1\nname broken\nrole probe\ncolour blue\n")
with open(os.path.join(lab, "notes.txt"), "w") as f:
    f.write("not a profile\n")

os.environ["ASPH_LINE_PROFILE_PATH"] = lab
d = run_json("drivers", "--json")
line = next((x for x in d["drivers"] if x["name"] == "line"), None)
expect(line is not None, "asph drivers --json has the line driver")
profiles = {p["name"]: p for p in line["profiles"]}
names = [p["name"] for p in line["profiles"]]
expect(names == sorted(names), "profiles sorted by name")
expect(all(n in profiles for n in built_ins), "every built-in profile is still listed")
expect(set(names) == set(built_ins) | {"lab-gauge", "broken"}, "nothing else is listed (notes.txt is not)")
g = profiles.get("lab-gauge", {})
expect(g.get("roles") == ["probe"] and g.get("description") == "our bench gauge"
       and g.get("path") == os.path.join(lab, "lab-gauge.profile") and g.get("error") is None,
       "the lab's own profile: roles, description, path")
pi = profiles.get("pi-gcs", {})
expect(pi.get("path") == os.path.join(lab, "pi-gcs.profile") and pi.get("roles") == ["stage"]
       and "C-884" in pi.get("reference", ""), "the lab's pi-gcs replaces the built-in one")
expect(profiles.get("sylvac", {}).get("path") == "built-in", "the others stay built in")
b = profiles.get("broken", {})
expect(b.get("roles") == [] and "broken.profile:4:1" in (b.get("error") or "")
       and "unknown keyword 'colour'" in b.get("error", ""), "a profile that does not load, with its reason")
expect(all(x["profiles"] == [] for x in d["drivers"] if x["name"] != "line"),
       "drivers without profile files list none")
opt = next(o for o in line["options"] if o["name"] == "profile")
expect("pi-gcs, newport" not in opt["help"] and "asph drivers" in opt["help"],
       "the profile option's help names no fixed list")

rc, out, _ = run("drivers")
expect(rc == 0 and "lab-gauge" in out and "our bench gauge" in out and
       "broken           does not load:" in out and os.path.join(lab, "pi-gcs.profile") in out,
       "asph drivers prints the profiles found, and why one does not load")

# a new file shows at the next listing: nothing is cached
os.remove(os.path.join(lab, "broken.profile"))
d = run_json("drivers", "--json")
line = next(x for x in d["drivers"] if x["name"] == "line")
expect("broken" not in [p["name"] for p in line["profiles"]], "the listing follows the directory")

# An override that is not there, or not a directory, is named with the
# setting to change: in the listing and when an instrument names a profile.
missing = os.path.join(lab, "no-such-dir")
for bad, why in ((missing, "No such file or directory"),
                 (os.path.join(lab, "notes.txt"), "Not a directory")):
    os.environ["ASPH_LINE_PROFILE_PATH"] = bad
    for args in (("drivers",), ("drivers", "--json"),
                 ("scan", "strong", "--method", "ci", "--h", "0.5", "--instrument",
                  "line:profile=pi-gcs", "-o", os.path.join(lab, "x.asphscan"))):
        rc, _, err = run(*args)
        what = " ".join(args[:2] if args[0] == "drivers" else args[:1])
        expect(rc == 1 and f"ASPH_LINE_PROFILE_PATH names {bad}: {why}" in err,
               f"asph {what}, ASPH_LINE_PROFILE_PATH={os.path.basename(bad)}: "
               f"refused, naming the setting ({err.strip()[-120:]})")
os.environ.pop("ASPH_LINE_PROFILE_PATH")

# Unreadable: a directory this user cannot search. Root reads any, so as
# root asph runs as nobody for these; another user meets a mode of 0.
NOBODY = ["setpriv", "--reuid", "65534", "--regid", "65534", "--clear-groups"]
as_root = os.geteuid() == 0
DENIED = "Permission denied"


def as_user(args, env=None):
    """(exit, stderr) of asph args as a user who cannot read a root-only folder."""
    p = subprocess.run([os.environ.get("ASPH_BIN", "asph"), *args], capture_output=True, text=True,
                       timeout=600, env=env, **({"user": 65534, "group": 65534, "extra_groups": []}
                                                 if as_root else {}))
    return p.returncode, p.stderr


shut = tempfile.mkdtemp(prefix="asph-test-shut-")
os.chmod(shut, 0o755)
locked = os.path.join(shut, "profiles")
os.mkdir(locked, 0o700 if as_root else 0)
rc, err = as_user(["drivers"], env={**os.environ, "ASPH_LINE_PROFILE_PATH": locked})
expect(rc == 1 and f"ASPH_LINE_PROFILE_PATH names {locked}: {DENIED} (set it" in err,
       f"ASPH_LINE_PROFILE_PATH not readable: refused, naming the setting ({err.strip()[-120:]})")
os.chmod(locked, 0o700)
shutil.rmtree(shut)

# The lab's directory (/etc/asphd/line-profiles installed from the
# package) may be absent, but one that is there and is not a directory
# this user can read is named with what to change. It is made in a mount
# namespace of the test's own, on an overlay of the folder that holds it:
# the machine's folders are untouched.
LAB_DIR = os.environ["ASPH_TEST_LAB_PROFILE_DIR"]
SAID = "(the lab's profile directory: make it a directory this user can read, or remove it)"


def in_namespace(make, cmd):
    """cmd with LAB_DIR made by the shell command make (the directory's
    path is $1); the completed process."""
    top = tempfile.mkdtemp(prefix="asph-test-overlay-")
    base = os.path.dirname(LAB_DIR)
    while not os.path.isdir(base):
        base = os.path.dirname(base)
    script = ('mount -t overlay overlay -o "lowerdir=$2,upperdir=$3/upper,workdir=$3/work" "$2" '
              '&& rm -rf "$1" && mkdir -p "$(dirname "$1")" && ' + make + ' && shift 3 && exec "$@"')
    os.mkdir(os.path.join(top, "upper"))
    os.mkdir(os.path.join(top, "work"))
    p = subprocess.run(["unshare", "-m", "--", "sh", "-c", script, "sh", LAB_DIR, base, top, *cmd],
                       capture_output=True, text=True, timeout=600)
    shutil.rmtree(top)
    return p


probe = in_namespace('mkdir "$1"', ["true"])
if probe.returncode != 0:
    print(f"# SKIP the lab's profile directory: no mount namespace or overlay here "
          f"({probe.stderr.strip()})")
else:
    wrap = getattr(sys.modules.get("sitecustomize"), "wrapped", list)
    for make, user, why in (('touch "$1"', False, "Not a directory"),
                            ('mkdir -m 700 "$1"', True, DENIED)):
        if user and not as_root:
            continue
        p = in_namespace(make, [*(NOBODY if user else []),
                                *wrap([os.environ.get("ASPH_BIN", "asph"), "drivers"])])
        expect(p.returncode == 1 and f"{LAB_DIR}: {why} {SAID}" in p.stderr,
               f"the lab's profile directory, {why.lower()}: asph drivers names it and what to "
               f"change (exit {p.returncode}: {p.stderr.strip()[-160:]})")
finish()
