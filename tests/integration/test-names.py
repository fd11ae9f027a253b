#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Every list of names agrees with the one table that defines it: the plan
methods (lib/plan/plan.c), their densities, the degrees of freedom, the
residuals, the presets, the verdicts, the uncertainty methods and the
quantities (libasph's tables as print-names prints them), the job states
(asphd's, as daemon.status counts them), the protocol's methods and the
roles they need (asphd's, as `asphd --list-methods` prints them) and the
drivers' options (as `asph drivers --json` lists them), wherever they are listed again: the
protocol's JSON Schemas and README, the manual pages and docs, the help
of asph and asphctl, asphctl's bash completion, the web page's names.js
and its rule of printing a quantity. A failure names the list and says
what differs."""
import glob
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

from daemontest import ASPHCTL, ASPHD, Client, Daemon, expect, finish, mock_instrument
from quantities import PRINT_NAMES, NO_SIGN, UNIT, format_quantity, tables

ASPH = os.environ.get("ASPH_BIN", "asph")
ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))


def read(*path):
    with open(os.path.join(ROOT, *path), encoding="utf-8") as f:
        return f.read()


def run(*argv, **kw):
    return subprocess.run(list(argv), capture_output=True, text=True, timeout=300, **kw)


def same(listed, table, what):
    expect(listed == table, f"{what}: {listed} is the table's {table}")


def schema_enums():
    """{(file, path): enum} of every enum in proto/schema and proto/mqtt."""
    found = {}

    def walk(o, f, path):
        if isinstance(o, dict):
            if "enum" in o:
                found[(f, path)] = o["enum"]
            for k, v in o.items():
                walk(v, f, f"{path}/{k}")
        elif isinstance(o, list):
            for i, v in enumerate(o):
                walk(v, f, f"{path}/{i}")
    for f in sorted(glob.glob(os.path.join(ROOT, "proto", "schema", "*.json")) +
                    glob.glob(os.path.join(ROOT, "proto", "mqtt", "*.json"))):
        with open(f) as fh:
            walk(json.load(fh), os.path.relpath(f, ROOT), "")
    return found


def check_schemas(t, states):
    enums = schema_enums()
    methods = [m["name"] for m in t["plan_methods"]]
    verdict_keys = sorted(q["verdict"] for q in t["quantities"] if q["verdict"])
    # what each enum lists, by the end of its path
    rules = [("/plan/properties/method", methods, "the plan methods"),
             ("/density", t["plan_densities"], "the plan densities"),
             ("/residual", t["residuals"], "the residuals"),
             ("/verdictName", t["verdicts"], "the verdicts"),
             ("/overall", t["verdicts"], "the verdicts"),
             ("/items/properties/verdict", t["verdicts"], "the verdicts"),
             ("/verdict/anyOf/0", t["verdicts"], "the verdicts"),
             ("/uncertainty_method", t["uncertainty_methods"], "the uncertainty methods"),
             ("/jobState", states, "the job states"),
             ("/properties/state", states, "the job states"),
             ("/previous/anyOf/0", states, "the job states")]
    checked = set()
    for (f, path), enum in enums.items():
        for suffix, table, what in rules:
            if path.endswith(suffix) and not (suffix == "/properties/state" and
                                              "job-state" not in f):
                same(enum, table, f"{f} {path}: {what}")
                checked.add(what)
        if path.endswith("/items/properties/quantity"):
            same(sorted(enum), verdict_keys, f"{f} {path}: the toleranced quantities")
            checked.add("quantities")
    expect(len(checked) == 7, f"every table's enum was found in the schemas ({sorted(checked)})")
    # the Monte Carlo's and the expanded uncertainties' members: every key
    # of the Monte Carlo is one of them
    common = json.loads(read("proto", "schema", "common.json"))
    fit = common["$defs"]["fitSummary"]["properties"]
    for name in ("uncertainty_k2", "uncertainty_standard"):
        props = set(fit[name]["properties"]) if name in fit else set()
        missing = [k for k in t["mc_quantities"] if k not in props]
        expect(props and not missing, f"common.json fitSummary.{name} has every Monte Carlo "
                                      f"key (missing {missing})")


def backticked(text):
    return re.findall(r"`([^`]+)`", text)


def check_docs(t):
    methods = [m["name"] for m in t["plan_methods"]]
    titles = [m["title"] for m in t["plan_methods"]]
    presets = t["presets"]
    readme = read("proto", "README.md")
    m = re.search(r"^- `plan` \(required\): `method` \((.*?)\) and exactly one of (.*?) "
                  r"\(docs/", readme, re.M | re.S)
    expect(m is not None, "proto/README.md: job.submit's plan")
    if m:
        same(backticked(m.group(1)), methods, "proto/README.md: the plan methods")
        same(backticked(m.group(2)), t["plan_densities"], "proto/README.md: the densities")
    m = re.search(r"^- `lens` \(required\): a preset name \((.*?)\)", readme, re.M)
    same(backticked(m.group(1)) if m else None, presets, "proto/README.md: the presets")
    m = re.search(r"`residual` \((.*?)\)", readme)
    same(re.findall(r"`([a-z]+)`", m.group(1)) if m else None, t["residuals"],
         "proto/README.md: the residuals")
    # the table of methods in docs/sampling-plans.md
    plans = read("docs", "sampling-plans.md")
    table = plans[plans.index("\n| method | name |"):].split("\n\n")[0]
    first = re.findall(r"^\| `([a-z]+)` \| ([^|]+?) \|", table, re.M)
    same([r[0] for r in first], methods, "docs/sampling-plans.md: the methods' table")
    same([r[1] for r in first], titles, "docs/sampling-plans.md: the methods' names in words")
    man = read("docs", "asphctl.1.md")
    m = re.search(r"LENS is a preset name \((.*?)\)", man, re.S)
    same(backticked(m.group(1)) if m else None, presets, "docs/asphctl.1.md: the presets")
    m = re.search(r"\[`--residual` ([a-z|]+)\]", man)
    same(m.group(1).split("|") if m else None, t["residuals"], "docs/asphctl.1.md: the residuals")


def help_item(text, term):
    """The text of an option in a help text, its lines joined."""
    m = re.search(rf"^  {re.escape(term)} +(.*(?:\n {{22}}\S.*)*)", text, re.M)
    return " ".join(m.group(1).split()) if m else None


def check_help(t):
    methods = [m["name"] for m in t["plan_methods"]]
    mesh = [m["name"] for m in t["plan_methods"] if m["mesh"]]
    presets = t["presets"]
    out = run(ASPH, "--help").stdout
    names = [ln.split()[0] for ln in out.split("Commands:\n", 1)[1].split("\n\n")[0].splitlines()]
    for name in names:
        text = run(ASPH, "help", name).stdout
        for m in re.finditer(r"LENS is a preset \(([^)]*)\)|\(a preset: ([^)]*?), or a", text):
            listed = [w for w in re.split(r"[,\s]+", m.group(1) or m.group(2)) if w]
            same(listed, presets, f"asph help {name}: the presets")
        item = help_item(text, "--method M")
        if item is not None:
            listed = re.findall(r"\b[a-z]+\b", item.replace("compute the plan instead:", "")
                                .split(";")[0])
            same(listed, methods, f"asph help {name}: the plan methods")
    text = run(ASPH, "help", "plan").stdout
    for term, pattern in (("-o, --output FILE", r"with faces for ([^)]*)\)"),
                          ("--no-mesh", r"the mesh of (.*) out")):
        m = re.search(pattern, help_item(text, term) or "")
        same(m.group(1).split(", ") if m else None, mesh,
             f"asph help plan {term}: the methods with a mesh")
    text = run(ASPH, "help", "fit").stdout
    dof = set(re.findall(r"\b(tx|ty|tz|rx|ry|rz|[A-Za-z]{1,2})\b", help_item(text, "--dof LIST")))
    expect(set(t["dof"]) <= dof, f"asph help fit --dof names every degree of freedom {t['dof']}")
    residual = help_item(text, "--residual KIND") or ""
    expect(all(re.search(rf"\b{r}\b", residual) for r in t["residuals"]),
           f"asph help fit --residual names {t['residuals']}")
    text = run(ASPHCTL, "help", "submit").stdout
    same(help_item(text, "--method M"), ", ".join(methods), "asphctl help submit: the methods")
    m = re.search(r"\(([^)]*)\)", help_item(text, "LENS") or "")
    same(m.group(1).split(", ") if m else None, presets, "asphctl help submit: the presets")
    m = re.search(r"--residual ([a-z|]+)\]", text)
    same(m.group(1).split("|") if m else None, t["residuals"], "asphctl help submit: --residual")


def complete(*words):
    """What asphctl's bash completion offers after words (the last one
    being completed), with the asphctl under test first in PATH, in an
    empty directory (no file names)."""
    script = (f"source {os.path.join(ROOT, 'tools', 'asphctl', 'asphctl.bash')}\n"
              f"COMP_WORDS=(asphctl {' '.join(repr(w) for w in words)})\n"
              f"COMP_CWORD={len(words)}\n_asphctl\nprintf '%s\\n' \"${{COMPREPLY[@]}}\"\n")
    with tempfile.TemporaryDirectory() as empty:
        env = dict(os.environ, PATH=os.path.dirname(os.path.abspath(shutil.which(ASPHCTL))) +
                   os.pathsep + os.environ.get("PATH", ""))
        p = run("bash", "-c", script, cwd=empty, env=env)
    return p.stdout.split()


def check_completion(t, states):
    if not shutil.which("bash"):
        print("# no bash: the completion is not checked")
        return
    same(complete("submit", "--method", ""), [m["name"] for m in t["plan_methods"]],
         "the completion of --method")
    same(complete("submit", "--residual", ""), t["residuals"], "the completion of --residual")
    same(complete("submit", ""), t["presets"], "the completion of submit's LENS")
    same(complete("list", "--state", ""), states, "the completion of --state")
    usage = run(ASPHCTL, "help", "queue").stdout.splitlines()[0]
    subs = re.findall(r"[\[|] ?([a-z]+)", usage.split("queue", 1)[1])
    same(complete("queue", ""), subs, "the completion of queue's subcommands")


def check_web(t):
    p = run(PRINT_NAMES, "--web")
    expect(p.returncode == 0 and read("daemon", "web", "names.js") == p.stdout,
           "daemon/web/names.js is what print-names --web prints (renew it with "
           "`print-names --web > daemon/web/names.js`)")
    node = shutil.which("node")
    if not node:
        print("# no node: the page's rule of printing a quantity is not checked")
        return
    # the page's rule against quantity_format()'s, on values that reach
    # each of its branches (not on a tie of binary fractions, such as
    # 123456.5 to six digits, which JavaScript rounds up and C to even: no
    # measured value is one)
    cases = []
    for q in t["quantities"]:
        for v in (1.23456789e-3, -0.004, 0.005000001, 733.1, -2.5e12, 1e-7, 123456.7, None):
            for flags in (0, UNIT, NO_SIGN, UNIT | NO_SIGN):
                cases.append((q["path"], v, flags))
    script = ("import { formatQuantity, quantityAt } from " +
              json.dumps("file://" + os.path.abspath(os.path.join(ROOT, "daemon", "web",
                                                                    "quantity.js"))) +
              ";\nconst cases = " + json.dumps(cases) + ";\n" +
              "console.log(JSON.stringify(cases.map(([p, v, f]) => "
              "formatQuantity(quantityAt(p), v === null ? NaN : v, f))));\n")
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "rule.mjs")
        with open(path, "w") as f:
            f.write(script)
        p = run(node, path)
    got = json.loads(p.stdout) if p.returncode == 0 else []
    by_path = {q["path"]: q for q in t["quantities"]}
    want = [format_quantity(by_path[pa], v, fl, by_path[pa]["symbol"]) for pa, v, fl in cases]
    bad = [(c, g, w) for c, g, w in zip(cases, got, want) if g != w]
    expect(p.returncode == 0 and len(got) == len(cases) and not bad,
           f"the page prints {len(cases)} cases as quantity_format() does {bad[:3]} {p.stderr}")


def check_driver_options():
    """Every option of every built-in driver is in its documentation: its
    docs/driver-NAME.md, or its section of docs/drivers.md; a family of
    per-axis options (x_min, y_min, z_min) by its x member."""
    out = run(ASPH, "drivers", "--json").stdout
    drivers = json.loads(out)["drivers"]
    general = read("docs", "drivers.md")
    for drv in drivers:
        name = drv["name"]
        path = os.path.join(ROOT, "docs", f"driver-{name}.md")
        if os.path.exists(path):
            text = read("docs", f"driver-{name}.md")
        else:
            m = re.search(rf"^## [^\n]*\(`{name}`\)\n(.*?)(?=^## |\Z)", general, re.M | re.S)
            text = m.group(1) if m else ""
        named = set(re.findall(r"`([a-z0-9_]+)(?:[`=])", text))
        missing = [o["name"] for o in drv["options"] if o["name"] not in named and
                   not (re.match(r"[yz]_", o["name"]) and "x" + o["name"][1:] in named)]
        expect(text and not missing, f"the documentation of driver {name} names every option "
                                     f"(missing {missing})")


def check_methods():
    """The protocol's methods are those of asphd's table, as `asphd
    --list-methods` prints it: each has its schema in proto/schema
    (METHOD.json, with its params and result), and each stands in the
    first row of proto/README.md's roles that may call it with the role it
    needs (hello, which needs none, in the viewers' row)."""
    out = run(ASPHD, "--list-methods")
    expect(out.returncode == 0 and out.stdout, f"asphd --list-methods runs ({out.stderr.strip()})")
    table = dict(line.split("\t") for line in out.stdout.splitlines())
    schemas = []
    for f in glob.glob(os.path.join(ROOT, "proto", "schema", "*.json")):
        with open(f) as fh:
            defs = json.load(fh).get("$defs", {})
        if "params" in defs and "result" in defs:
            schemas.append(os.path.basename(f)[:-len(".json")])
    expect(set(schemas) == set(table),
           "proto/schema has a schema for each method of asphd's table and for no other "
           f"(without a schema: {sorted(set(table) - set(schemas))}; "
           f"not in the table: {sorted(set(schemas) - set(table))})")
    m = re.search(r"^\| role \| may call \|\n\|---\|---\|\n((?:\|.*\n)+)",
                  read("proto", "README.md"), re.M)
    expect(m, "proto/README.md has the table of roles (\"| role | may call |\")")
    listed = {}
    for row in m.group(1).splitlines() if m else []:
        role, calls = (x.strip() for x in row.strip("|").split("|"))
        # a method's name; an argument (`force`) is not one
        for name in re.findall(r"`([a-z_]+(?:\.[a-z_]+)?)`", calls):
            if "." in name or name in table:
                listed.setdefault(name, role)
    want = {name: "viewer" if role == "none" else role for name, role in table.items()}
    differ = {name: (listed.get(name), want.get(name)) for name in sorted(set(listed) | set(want))
              if listed.get(name) != want.get(name)}
    expect(not differ, "proto/README.md's roles list each method of asphd's table with the "
                       f"role it needs (README, table: {differ})")


def main():
    t = tables()
    d = Daemon([mock_instrument()])
    try:
        d.start()
        c = Client(d.socket)
        states = list(c.call("daemon.status")["jobs"].keys())
        c.close()
        d.stop()
    finally:
        d.cleanup()
    expect(len(states) >= 7, f"asphd counts its jobs by every state {states}")
    check_schemas(t, states)
    check_docs(t)
    check_help(t)
    check_completion(t, states)
    check_web(t)
    check_driver_options()
    check_methods()
    finish()


if __name__ == "__main__":
    sys.exit(main())
