#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph drivers lists the line driver's profiles as the profile
directories hold them: a lab's own, one that replaces a built-in of the
same name, and one that does not load (with its reason)."""
import os
import shutil
import sys
import tempfile

from asphtest import expect, finish, run, run_json

builtin = os.environ.get("ASPH_LINE_PROFILE_PATH", "")
if not builtin:
    print("the line driver is not built (-Ddrivers): skipped")
    sys.exit(77)

tmp = tempfile.TemporaryDirectory(prefix="asph-test-profiles-")
lab = tmp.name
# a lab's own gauge, a copy of the built-in Sylvac profile renamed
with open(os.path.join(builtin, "sylvac.profile")) as f:
    text = f.read()
with open(os.path.join(lab, "lab-gauge.profile"), "w") as f:
    f.write(text.replace("name sylvac", "name lab-gauge")
            .replace('description "Sylvac gauge (Opto RS232)"', 'description "our bench gauge"'))
# a lab's pi-gcs replaces the built-in one
shutil.copy(os.path.join(builtin, "pi-gcs.profile"), os.path.join(lab, "pi-gcs.profile"))
# one that does not load, and a file that is not a profile by its name
with open(os.path.join(lab, "broken.profile"), "w") as f:
    f.write("asphd-line-profile 1\nname broken\nrole probe\ncolour blue\n")
with open(os.path.join(lab, "notes.txt"), "w") as f:
    f.write("not a profile\n")

os.environ["ASPH_LINE_PROFILE_PATH"] = lab + ":" + builtin
d = run_json("drivers", "--json")
line = next((x for x in d["drivers"] if x["name"] == "line"), None)
expect(line is not None, "asph drivers --json has the line driver")
profiles = {p["name"]: p for p in line["profiles"]}
names = [p["name"] for p in line["profiles"]]
expect(names == sorted(names), "profiles sorted by name")
built_ins = sorted(f[:-len(".profile")] for f in os.listdir(builtin) if f.endswith(".profile"))
expect(all(n in profiles for n in built_ins), "every built-in profile is listed: " + ", ".join(built_ins))
expect(set(names) == set(built_ins) | {"lab-gauge", "broken"}, "nothing else is listed (notes.txt is not)")
g = profiles.get("lab-gauge", {})
expect(g.get("roles") == ["probe"] and g.get("description") == "our bench gauge"
       and g.get("path") == os.path.join(lab, "lab-gauge.profile") and g.get("error") is None,
       "the lab's own profile: roles, description, path")
pi = profiles.get("pi-gcs", {})
expect(pi.get("path") == os.path.join(lab, "pi-gcs.profile") and pi.get("roles") == ["stage"]
       and "C-884" in pi.get("reference", ""), "the lab's pi-gcs replaces the built-in one")
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
finish()
