#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""What proto/README.md promises of the wire beyond the schemas: a UTF-8
byte-order mark at the start of a line is skipped (anywhere else it is a
parse error, whose column counts it); a numeric id comes back as the same
number, an integer as the same text and any other number as the same
double; job.result returns what the README and the schema say it
does, no member more or less; and a subscribed client's events never split
the line of a batch's answers."""
import json
import os
import re
import sys

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import Client, Daemon, expect, finish, poll_state  # noqa: E402
from protoschema import SchemaSet  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
PROTO = os.path.join(ROOT, "proto")
BOM = b"\xef\xbb\xbf"


def raw(c, data):
    """Sends data (one line) and returns the text of the answer's line."""
    c.send_raw(data)
    return c.read_line()


def version(rid):
    return b'{"jsonrpc":"2.0","id":' + rid + b',"method":"version"}'


d = Daemon()
try:
    d.start()
    c = Client(d.socket)

    # --- a byte-order mark
    r = json.loads(raw(c, BOM + version(b"1") + b"\n"))
    expect(r.get("result", {}).get("server") == "asphd" and r.get("id") == 1,
           f"a byte-order mark at the start of a line is skipped ({r})")
    r = json.loads(raw(c, BOM + b'[' + version(b"2") + b"," + version(b"3") + b"]\n"))
    expect(isinstance(r, list) and sorted(x.get("id") for x in r) == [2, 3],
           "before a batch too")
    for name, data, column in (("twice", BOM + BOM + version(b"4"), 2),
                               ("after a space", b" " + BOM + version(b"5"), 2),
                               ("inside", version(b"6")[:-1] + BOM + b"}", None),
                               ("alone", BOM, None)):
        r = json.loads(raw(c, data + b"\n"))
        err = r.get("error", {})
        detail = err.get("data", {}).get("detail", "")
        # a column where jansson knows one; never "column -1"
        m = re.match(r"column (\d+): ", detail)
        expect(err.get("code") == -32700 and "-1" not in detail and
               (column is None or (m and int(m.group(1)) == column)),
               f"a byte-order mark {name}: a parse error{'' if column is None else f' at column {column}'}"
               f" ({detail})")
    expect(c.call("version")["server"] == "asphd", "the connection goes on")

    # --- numeric ids: the same number; integers as sent, other numbers as
    # the same double in 17 significant digits (proto/README.md)
    for sent, back in ((b"7", b"7"), (b"-12", b"-12"), (b"9223372036854775807", b"9223372036854775807"),
                       (b"1.50", b"1.5"), (b"1e2", b"100.0"), (b"1E2", b"100.0"), (b"2.5", b"2.5"),
                       (b"0.1", b"0.10000000000000001"), (b"-0.0", b"-0.0"),
                       (b"3.141592653589793238", b"3.1415926535897931"),
                       (b"1e300", b"1.0000000000000001e300")):
        line = raw(c, version(sent) + b"\n")
        m = re.search(rb'"id":(-?[0-9.eE+-]+)', line)
        expect(m and m.group(1) == back and json.loads(m.group(1)) == json.loads(sent),
               f"id {sent.decode()} comes back as {back.decode()}, the same number "
               f"({m and m.group(1).decode()})")
    r = json.loads(raw(c, version(b"9223372036854775808") + b"\n"))
    expect(r.get("error", {}).get("code") == -32700 and r.get("id") is None,
           f"an integer id past 64 bits is a parse error ({r})")
    for sid in ('"a"', '"1.50"', '""', "null"):
        line = raw(c, version(sid.encode()) + b"\n")
        expect(b'"id":' + sid.encode() in line, f"id {sid} comes back as sent")

    # --- job.result as documented
    c.call("events.subscribe", {"events": ["job"]})
    job = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300},
                                "label": "wire"})["id"]
    expect(poll_state(c, job, ["completed", "failed"])["state"] == "completed", "a job completes")
    res = c.call("job.result", {"id": job})

    # the members at each level the README describes
    levels = {"": res, "summary": res["summary"], "provenance": res["provenance"],
              "provenance.plan": res["provenance"]["plan"],
              "provenance.software": res["provenance"]["software"],
              "provenance.submitted_by": res["provenance"]["submitted_by"],
              "provenance.scan": res["provenance"]["scan"], "files": res["files"],
              "summary.acquisition": res["summary"]["acquisition"],
              "summary.acquisition.positions": res["summary"]["acquisition"]["positions"],
              "summary.acquisition.drift": res["summary"]["acquisition"]["drift"]}
    returned = {k for obj in levels.values() for k in obj}
    with open(os.path.join(PROTO, "README.md")) as f:
        readme = f.read()
    section = re.search(r"^### `job\.result`\n(.*?)^### ", readme, re.S | re.M).group(1)
    documented = set(re.findall(r"`([a-z][a-z0-9_-]*)`", section))
    expect(returned <= documented, f"the README documents every member job.result returns "
                                   f"(missing: {sorted(returned - documented)})")
    # the params (id) and the file names' descriptions aside, nothing more;
    # the Monte Carlo's members come only with an instrument that declares
    # uncertainty contributions (test-daemon-uncertainty.py has them), the
    # curvature's only with R fitted and the traces' only for line profiles
    # (test-cli-profiles.py has both), and the plan chosen for the
    # tolerance only for a job submitted with plan.for_tolerance
    # (test-daemon-plan-tolerance.py has it), the measured data's only for
    # a job of measured data (test-daemon-measured.py)
    conditional = {"uncertainty_standard", "uncertainty_model", "c", "c_per_mm",
                   "nominal_c_per_mm", "azimuth_deg", "offset_mm", "length_mm",
                   "slope_max_urad", "n_slope_positions", "plan_for_tolerance", "measured"}
    extra = documented - returned - {"id"} - conditional
    expect(not extra, f"the README documents no member job.result does not return ({sorted(extra)})")

    schemas = SchemaSet(os.path.join(PROTO, "schema"))
    result_schema = schemas.files["job.result.json"]["$defs"]["result"]
    common = schemas.files["common.json"]["$defs"]

    def props(schema, path):
        for part in path.split(".") if path else []:
            schema = schema["properties"][part]
            if "$ref" in schema:
                schema = common[schema["$ref"].split("/")[-1]]
        return schema

    for path, obj in levels.items():
        schema = props(result_schema, path)
        named = set(schema.get("properties", {}))
        expect(set(obj) <= named and set(schema.get("required", [])) <= set(obj),
               f"job.result {path or 'top'}: the members are the schema's "
               f"(returned {sorted(set(obj) - named)} not in it, required "
               f"{sorted(set(schema.get('required', [])) - set(obj))} missing)")
        expect(named <= documented, f"job.result {path or 'top'}: every member of the schema "
                                    f"is documented ({sorted(named - documented)})")
    # result.json in the job's folder is the answer without "dir"
    with open(os.path.join(res["dir"], "result.json")) as f:
        on_disk = json.load(f)
    expect(on_disk == {k: v for k, v in res.items() if k != "dir"},
           "result.json holds job.result's answer but dir")

    # A notification never splits an answer's line: a subscribed client's
    # batch submits jobs, whose events come while the batch's answers are
    # being written, and each event gets a line of its own, before the
    # array or after it.
    w = Client(d.socket)
    w.call("events.subscribe", {"events": ["job"]})
    w.call("queue.stop")
    batch = [{"jsonrpc": "2.0", "id": i, "method": "job.list", "params": {"limit": 50}}
             for i in range(200)]
    for i in range(0, 200, 40):
        batch[i] = {"jsonrpc": "2.0", "id": i, "method": "job.submit",
                    "params": {"lens": "weak", "plan": {"method": "ci", "h": 0.2},
                               "label": f"in a batch {i}"}}
    w.send_raw(json.dumps(batch).encode() + b"\n")
    answers, events, unparsable = None, [], []
    while answers is None:
        line = w.read_line()
        try:
            m = json.loads(line)
        except ValueError as e:
            unparsable.append(f"{e}: {line[:80]!r}")
            if line.startswith(b"["):
                answers = []
            continue
        if isinstance(m, list):
            answers = m
        else:
            events.append(m)
    submitted = {a["result"]["id"] for a in answers if a["id"] % 40 == 0 and "result" in a}
    expect(not unparsable and [a["id"] for a in answers] == list(range(200)) and len(submitted) == 5,
           f"a batch answered on one line among events ({unparsable[:2]})")
    w.call("daemon.status")
    seen = {e["params"].get("job") for e in events + w.events if e["method"].startswith("job.")}
    expect(submitted <= seen, f"every submitted job's event arrived, on its own line "
                              f"({sorted(submitted - seen)} missing)")
    for job in submitted:
        w.call("job.cancel", {"id": job})
    w.call("queue.start")
    w.close()
    c.close()
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
