# SPDX-License-Identifier: GPL-3.0-or-later
"""The protocol part of the bad-input corpus: malformed JSON-RPC requests
for asphd (proto/README.md), generated from one valid request per method by
mutations: truncation, wrong types of every parameter and of the envelope,
huge numbers, deep nesting, invalid UTF-8 and NUL characters, oversized
lines, unknown and duplicate members, NaN and Infinity, batches and
notifications, blank lines, binary garbage, requests split across writes.

Each case is a PCase(category, name, send, answers, conn):

  send     the bytes written (a request line ends with "\\n"); a list of
           byte strings is written one write() each; a function returns an
           iterator of chunks (the 100 MB lines).
  answers  what the daemon must answer, in order: one entry per response,
           Err(code, detail, id, column) for an error (detail: a regular
           expression the error's data.detail must match, naming the field
           or the position; id: the id the response must carry; column:
           (lo, hi) bounds of the column a parse error names, or None), OK
           for a result, a list of those for a batch response (any order).
           An empty list: no response at all.
  conn     'shared': one connection for all such cases, in order;
           'eof': its own connection, half-closed after sending, which the
           daemon must close after its answers;
           'flood': its own connection, the sending in a thread while
           another connection checks that the daemon answers;
           'stall': its own connection that stops inside a request and
           must get -32003 and be closed, checked after the corpus.

What each case is fed to and checked for is in test-badinput-protocol.py.
Everything is deterministic: the same cases every run.
"""
import json
import random
import re
from collections import namedtuple

PCase = namedtuple("PCase", "category name send answers conn")
Err = namedtuple("Err", "code detail id column")
OK = "result"

MAX_REQUEST = 1 << 20     # limits.max_request_bytes, the default
MAX_BATCH = 1000          # PROTO_MAX_BATCH, proto/asph-proto.h
INSTRUMENT = "bench"      # the configured instrument the requests name

PARSE, INVALID, NO_METHOD, PARAMS = -32700, -32600, -32601, -32602
TOO_LARGE, TIMEOUT = -32000, -32003
LIMIT, LENS, PLAN, NO_JOB = 104, 105, 106, 101

ABSENT = object()

# One valid request per method of proto/README.md, every parameter given.
# Job 1 exists (the reference run); none is ever changed by the corpus.
REQUESTS = {
    "hello": {"client": "badinput-corpus"},
    "version": ABSENT,
    "daemon.status": ABSENT,
    "job.submit": {"lens": "strong", "plan": {"method": "ci", "h": 0.31},
                   "fit": {"dof": "tx,ty,tz,rx,ry", "residual": "normal", "robust": False,
                           "zernike": 21},
                   "instrument": INSTRUMENT, "priority": 7, "label": "corpus"},
    "job.get": {"id": 1, "history": True},
    "job.list": {"states": ["completed", "failed"], "instrument": INSTRUMENT, "label": "corpus",
                 "uid": 0, "mine": False, "offset": 0, "limit": 10},
    "job.cancel": {"id": 1},
    "job.pause": {"id": 1},
    "job.resume": {"id": 1},
    "job.requeue": {"id": 1, "restart": True},
    "job.result": {"id": 1},
    "queue.get": ABSENT,
    "queue.move": {"id": 1, "position": 0},
    "queue.start": ABSENT,
    "queue.stop": {"abort": False},
    "instrument.list": ABSENT,
    "instrument.status": {"name": INSTRUMENT},
    "driver.list": ABSENT,
    "events.subscribe": {"events": ["job", "progress"], "job": 1},
    "events.unsubscribe": ABSENT,
    "daemon.health": ABSENT,
    # (the corpus's connection has made no copy: every valid request of it
    # is answered 107, and each mutation below by its error first)
    "backup.file": {"offset": 0, "length": 64},
}

PRESCRIPTION = {"type": "even_asphere", "name": "corpus", "R": 23.713, "k": -0.83,
                "A": {"4": -1.9317e-5, "6": 2.771e-9}, "aperture_diameter": 31.4}
QBFS = {"type": "qbfs", "R": 31.7, "norm_radius": 10, "a": [0.0213, -0.0071, 0.0032],
        "aperture_diameter": 20}


def request(method, params=None, rid=1, **extra):
    """A request object: params None means the template's."""
    r = {"jsonrpc": "2.0", "id": rid, "method": method}
    p = REQUESTS.get(method, ABSENT) if params is None else params
    if p is not ABSENT:
        r["params"] = p
    r.update(extra)
    return r


def text(obj):
    return json.dumps(obj, separators=(",", ":"), ensure_ascii=False).encode()


def line(obj):
    return text(obj) + b"\n"


def copy_set(obj, path, value):
    """A deep copy of obj with the member at path replaced (or removed
    when value is ABSENT)."""
    obj = json.loads(json.dumps(obj))
    node = obj
    for key in path[:-1]:
        node = node[key]
    if value is ABSENT:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return obj


MARK = "@@RAW@@"


def with_raw(obj, path, raw):
    """obj as a line with the value at path replaced by raw bytes (any
    bytes: NaN, 1e400, invalid UTF-8, ...); also the byte offsets where raw
    starts and ends."""
    t = text(copy_set(obj, path, MARK))
    at = t.index(b'"' + MARK.encode() + b'"')
    raw = raw if isinstance(raw, bytes) else raw.encode()
    return t[:at] + raw + t[at + len(MARK) + 2:] + b"\n", at, at + len(raw) - 1


def column(data, offset):
    """jansson's column of the byte at offset: it counts characters (a
    byte that starts a UTF-8 sequence or is ASCII), 1-based."""
    return sum(1 for b in data[:offset + 1] if b < 0x80 or 0xc2 <= b <= 0xf4)


def parse_error(data, first, last, slack=1):
    """Err of a line that jansson must refuse at a fault between the byte
    offsets first and last."""
    return Err(PARSE, r"^column \d+: ", None,
               (max(0, column(data, first) - slack), column(data, last) + slack))


def end_error(data):
    """Err of a line refused where it ends (truncated)."""
    body = data.rstrip(b"\n")
    n = column(body, len(body) - 1) if body else 0
    return Err(PARSE, r"^column \d+: ", None, (max(0, n - 1), n + 1))


def depth_error(data, limit=2048):
    """Err of a line nested deeper than jansson's limit: the column of the
    bracket that opens level limit + 1."""
    depth, in_string, escaped = 0, False, False
    for i, b in enumerate(data):
        if in_string:
            if escaped:
                escaped = False
            elif b == 0x5c:
                escaped = True
            elif b == 0x22:
                in_string = False
        elif b == 0x22:
            in_string = True
        elif b in (0x5b, 0x7b):
            depth += 1
            if depth > limit:
                return parse_error(data, i, i)
        elif b in (0x5d, 0x7d):
            depth -= 1
    raise AssertionError("not nested deeper than %d" % limit)


def quoted(name):
    return re.escape('"%s"' % name)


# ------------------------------------------------------------ truncation

def truncation_cases():
    cases = []
    for method in REQUESTS:
        full = text(request(method, rid=100))
        m = full.index(b'"method":"') + len(b'"method":"')
        cuts = {1, m, m + len(method) // 2}
        cuts.update(len(full) * k // 7 for k in range(1, 7))
        cuts.add(len(full) - 1)
        for cut in sorted(c for c in cuts if 0 < c < len(full)):
            data = full[:cut] + b"\n"
            cases.append(PCase("truncated JSON", "%s-cut-at-%d" % (method, cut), data,
                               [end_error(data)], "shared"))
    # Truncated in other ways: the string, the escape, the number, the
    # literal; inside a multi-byte character.
    label = text(request("job.submit", copy_set(REQUESTS["job.submit"], ["label"], "d\u00e9j\u00e0")))
    at = label.index("\u00e9".encode()) + 1
    for name, data in [("inside-an-escape", b'{"jsonrpc":"2.0","id":7,"method":"ver\\u00'),
                       ("after-a-backslash", b'{"jsonrpc":"2.0","id":7,"method":"ver\\'),
                       ("inside-true",
                        b'{"jsonrpc":"2.0","id":7,"method":"job.get","params":{"id":1,"history":tr'),
                       ("inside-an-exponent", b'{"jsonrpc":"2.0","id":1e'),
                       ("inside-a-character", label[:at]),
                       ("key-without-value", b'{"jsonrpc":"2.0","id":7,"method":'),
                       ("object-without-colon", b'{"jsonrpc"'),
                       ("open-brace", b"{"), ("open-bracket", b"["), ("open-quote", b'"')]:
        cases.append(PCase("truncated JSON", name, data + b"\n", [end_error(data)], "shared"))
    # The input ends inside a request: answered, then the daemon closes.
    ended = [Err(PARSE, "the input ended inside a request", None, None)]
    for name, data, before in [
            ("eof-after-one-byte", b"{", []),
            ("eof-inside-a-string", b'{"jsonrpc":"2.0","id":7,"method":"job.li', []),
            ("eof-inside-a-character", label[:at], []),
            ("eof-after-a-complete-request",
             line(request("version", rid=8)) + b'{"jsonrpc":"2.0","id":9,', [OK]),
            ("eof-after-a-carriage-return", b'{"jsonrpc":"2.0","id":9,"method":"version"}\r', [])]:
        cases.append(PCase("truncated JSON", name, data, before + ended, "eof"))
    return cases


# ------------------------------------------------------------ wrong types

WRONG = {
    "int": [("string", "7"), ("real", 2.5), ("bool", True), ("array", [7]), ("object", {"v": 7}),
            ("null", None)],
    "string": [("number", 7), ("bool", False), ("array", ["x"]), ("object", {"s": "x"}),
               ("null", None)],
    "bool": [("string", "true"), ("number", 1), ("array", [True]), ("object", {}), ("null", None)],
    "object": [("string", "ci"), ("number", 3), ("array", []), ("bool", True), ("null", None)],
    "number": [("string", "0.31"), ("bool", True), ("array", [0.31]), ("object", {"v": 0.31}),
               ("null", None)],
    "lens": [("number", 20.1), ("bool", True), ("array", ["strong"]), ("null", None)],
    "flags": [("string", "job"), ("number", 1), ("object", {"0": "job"}), ("bool", True),
              ("null", None), ("element-number", [1]), ("element-null", [None]),
              ("element-array", [["job"]]), ("element-unknown", ["everything"])],
}

SUBMIT = REQUESTS["job.submit"]
# measured data in place of a plan: no descriptor comes on this connection,
# and each wrong type is refused naming its member before one is looked for
MEASURED = {"lens": "strong", "measured": {"fd": 0, "format": "auto", "units": "mm"}}
PARAM_TYPES = [
    ("hello", None, ["client"], "string"), ("hello", None, ["token"], "string"),
    ("job.submit", None, ["lens"], "lens"), ("job.submit", None, ["plan"], "object"),
    ("job.submit", None, ["plan", "method"], "string"),
    ("job.submit", None, ["plan", "h"], "number"),
    ("job.submit", copy_set(SUBMIT, ["plan"], {"method": "raster", "spacing": 3.1}),
     ["plan", "spacing"], "number"),
    ("job.submit", copy_set(SUBMIT, ["plan"], {"method": "fermat", "points": 61}),
     ["plan", "points"], "number"),
    ("job.submit", copy_set(SUBMIT, ["plan"], {"method": "profiles", "h": 0.05, "profiles": 2}),
     ["plan", "profiles"], "int"),
    ("job.submit", None, ["fit"], "object"), ("job.submit", None, ["fit", "dof"], "string"),
    ("job.submit", None, ["fit", "residual"], "string"),
    ("job.submit", None, ["fit", "robust"], "bool"),
    ("job.submit", None, ["fit", "zernike"], "int"),
    ("job.submit", None, ["instrument"], "string"), ("job.submit", None, ["priority"], "int"),
    ("job.submit", None, ["label"], "string"),
    ("job.submit", MEASURED, ["measured"], "object"),
    ("job.submit", MEASURED, ["measured", "fd"], "int"),
    ("job.submit", MEASURED, ["measured", "format"], "string"),
    ("job.submit", MEASURED, ["measured", "units"], "string"),
    ("job.get", None, ["id"], "int"), ("job.get", None, ["history"], "bool"),
    ("job.list", None, ["states"], "flags"), ("job.list", None, ["instrument"], "string"),
    ("job.list", None, ["label"], "string"), ("job.list", None, ["uid"], "int"),
    ("job.list", None, ["mine"], "bool"), ("job.list", None, ["offset"], "int"),
    ("job.list", None, ["limit"], "int"),
    ("job.cancel", None, ["id"], "int"), ("job.pause", None, ["id"], "int"),
    ("job.resume", None, ["id"], "int"), ("job.requeue", None, ["id"], "int"),
    ("job.requeue", None, ["restart"], "bool"), ("job.result", None, ["id"], "int"),
    ("queue.move", None, ["id"], "int"), ("queue.move", None, ["position"], "int"),
    ("queue.stop", None, ["abort"], "bool"),
    ("instrument.status", None, ["name"], "string"),
    ("events.subscribe", None, ["events"], "flags"), ("events.subscribe", None, ["job"], "int"),
    ("backup.file", None, ["offset"], "int"), ("backup.file", None, ["length"], "int"),
]


def wrong_type_cases():
    cases = []
    rid = 2000
    for method, params, path, kind in PARAM_TYPES:
        leaf = path[-1]
        for tname, value in WRONG[kind]:
            base = request(method, params, rid=rid)
            if kind == "flags" and tname.startswith("element"):
                detail = quoted(leaf) + r"\[0\]"
            else:
                detail = quoted(leaf)
            cases.append(PCase("wrong types", "%s-%s-%s" % (method, ".".join(path), tname),
                               line(copy_set(base, ["params"] + path, value)),
                               [Err(PARAMS, detail, rid, None)], "shared"))
            rid += 1
    # The envelope: the request itself, id, jsonrpc, method, params.
    v = request("version", rid=3000)
    for tname, value in [("number", 42), ("string", "version"), ("null", None), ("true", True),
                         ("real", 1.5)]:
        cases.append(PCase("wrong types", "request-is-a-" + tname, line(value),
                           [Err(INVALID, "must be an object", None, None)], "shared"))
    for tname, value in [("object", {}), ("array", [1]), ("bool", True), ("false", False),
                         ("nested", [[3000]])]:
        cases.append(PCase("wrong types", "id-" + tname, line(copy_set(v, ["id"], value)),
                           [Err(INVALID, quoted("id"), None, None)], "shared"))
    for tname, value in [("number", 2.0), ("old-version", "1.0"), ("two", "2"), ("null", None),
                         ("array", ["2.0"]), ("spaces", " 2.0"), ("missing", ABSENT),
                         ("with-nul", "2.0\u0000")]:
        cases.append(PCase("wrong types", "jsonrpc-" + tname, line(copy_set(v, ["jsonrpc"], value)),
                           [Err(INVALID, quoted("jsonrpc"), 3000, None)], "shared"))
    for tname, value in [("number", 7), ("null", None), ("array", ["version"]),
                         ("object", {"name": "version"}), ("bool", True), ("missing", ABSENT)]:
        cases.append(PCase("wrong types", "method-" + tname, line(copy_set(v, ["method"], value)),
                           [Err(INVALID, quoted("method"), 3000, None)], "shared"))
    for tname, value in [("empty", ""), ("uppercase", "Version"), ("trailing-space", "version "),
                         ("leading-slash", "/version"), ("event-name", "job.state"),
                         ("rpc-internal", "rpc.discover"), ("very-long", "v" * 10000)]:
        shown = re.escape(value[:64])
        cases.append(PCase("wrong types", "method-" + tname, line(copy_set(v, ["method"], value)),
                           [Err(NO_METHOD, 'no method "%s' % shown, 3000, None)], "shared"))
    g = request("job.get", rid=3001)
    for tname, value in [("string", "id=1"), ("number", 1), ("bool", True), ("null", None)]:
        cases.append(PCase("wrong types", "params-" + tname, line(copy_set(g, ["params"], value)),
                           [Err(INVALID, quoted("params"), 3001, None)], "shared"))
    for tname, value in [("positional", [1]), ("positional-two", [1, True]),
                         ("positional-object", [{"id": 1}])]:
        cases.append(PCase("wrong types", "params-" + tname, line(copy_set(g, ["params"], value)),
                           [Err(PARAMS, "params must be an object", 3001, None)], "shared"))
    return cases


# ------------------------------------------------------------ huge numbers

I63 = 2 ** 63


def huge_number_cases():
    cases = []
    rid = 4000

    def add(name, obj, path, raw, answer):
        nonlocal rid
        data, first, last = with_raw(obj, path, raw)
        if answer == "parse":
            answer = parse_error(data, first, last)
        cases.append(PCase("huge numbers", name, data, [answer], "shared"))
        rid += 1

    too_big = [("2^63", str(I63)), ("2^64", str(2 ** 64)), ("-2^63-1", str(-I63 - 1)),
               ("400-digits", "7" * 400), ("1e400", "1e400"), ("-1e400", "-1e400")]
    # The request id: out of range is a parse error; in range it comes back.
    for name, raw in too_big:
        add("id-" + name, request("version", rid=0), ["id"], raw, "parse")
    for name, raw, back in [("2^63-1", str(I63 - 1), I63 - 1), ("-2^63", str(-I63), -I63),
                            ("1e-400", "1e-400", 0.0), ("minus-zero", "-0", 0),
                            ("largest-double", "1.7976931348623157e308", 1.7976931348623157e308),
                            ("smallest-double", "5e-324", 5e-324)]:
        add("id-%s-echoed" % name, request("no.such.method", ABSENT, rid=0), ["id"], raw,
            Err(NO_METHOD, 'no method "no.such.method"', back, None))
    # Job ids.
    jg = request("job.get", {"id": 1}, rid=1)
    for name, raw in too_big:
        add("job-id-" + name, jg, ["params", "id"], raw, "parse")
    for name, raw in [("zero", "0"), ("minus-zero", "-0"), ("minus-one", "-1"), ("-2^63", str(-I63)),
                      ("1e-400", "1e-400"), ("1e19-real", "1e19"), ("long-fraction", "1." + "0" * 900 + "1")]:
        add("job-id-" + name, jg, ["params", "id"], raw, Err(PARAMS, quoted("id"), 1, None))
    add("job-id-2^63-1-unknown", jg, ["params", "id"], str(I63 - 1),
        Err(NO_JOB, str(I63 - 1), 1, None))
    # Priorities.
    sub = request("job.submit", rid=1)
    for name, raw in too_big[:2] + too_big[4:5]:
        add("priority-" + name, sub, ["params", "priority"], raw, "parse")
    for name, raw in [("2^63-1", str(I63 - 1)), ("-2^63", str(-I63)), ("1001", "1001"),
                      ("-1001", "-1001"), ("1e-400", "1e-400"), ("1e3-real", "1e3")]:
        add("priority-" + name, sub, ["params", "priority"], raw, Err(PARAMS, quoted("priority"), 1, None))
    # Counts: paging, uid, queue position, subscription job, Zernike terms.
    for method, path, values in [
            ("job.list", ["limit"], [("zero", "0"), ("1001", "1001"), ("2^63-1", str(I63 - 1)),
                                     ("-1", "-1")]),
            ("job.list", ["offset"], [("-1", "-1"), ("-2^63", str(-I63))]),
            ("job.list", ["uid"], [("-1", "-1"), ("2^32", str(2 ** 32)), ("2^63-1", str(I63 - 1))]),
            ("queue.move", ["position"], [("-1", "-1"), ("-2^63", str(-I63))]),
            ("events.subscribe", ["job"], [("zero", "0"), ("-2^63", str(-I63))]),
            ("job.submit", ["fit", "zernike"], [("zero", "0"), ("67", "67"), ("2^62", str(2 ** 62)),
                                                ("-2^63", str(-I63))])]:
        obj = request(method, rid=1)
        for name, raw in values:
            add("%s-%s-%s" % (method, ".".join(path), name), obj, ["params"] + path, raw,
                Err(PARAMS, quoted(path[-1]), 1, None))
        add("%s-%s-2^64" % (method, ".".join(path)), obj, ["params"] + path, str(2 ** 64), "parse")
    # Plan densities.
    for method, key, values in [
            ("fermat", "points", [("zero", "0", PARAMS), ("minus-zero", "-0", PARAMS), ("-3", "-3", PARAMS),
                                  ("1e13", "1e13", PARAMS), ("1e-400", "1e-400", PARAMS),
                                  # (refused by its number before the surface is built)
                                  ("1e12", "1e12", LIMIT), ("6e6", "6000000", LIMIT)]),
            ("ci", "h", [("minus-zero", "-0.0", PARAMS), ("1e-400", "1e-400", PARAMS),
                         ("1e300", "1e300", PARAMS), ("1e-9", "1e-9", PLAN), ("4.2", "4.2", PLAN)]),
            ("raster", "spacing", [("1e-10", "1e-10", PARAMS), ("1e13", "1e13", PARAMS),
                                   ("1e-9", "1e-9", PLAN), ("1e12", "1e12", PLAN)])]:
        obj = request("job.submit", copy_set(SUBMIT, ["plan"], {"method": method, key: 1}), rid=1)
        for name, raw, code in values:
            detail = {PARAMS: quoted(key), PLAN: quoted("plan"),
                      LIMIT: "more than the limit of 5000000"}[code]
            add("plan-%s-%s-%s" % (method, key, name), obj, ["params", "plan", key], raw,
                Err(code, detail, 1, None))
        for name, raw in [("2^64", str(2 ** 64)), ("1e400", "1e400")]:
            add("plan-%s-%s-%s" % (method, key, name), obj, ["params", "plan", key], raw, "parse")
    # The profiles plan's count: 1..36, and only with its method.
    obj = request("job.submit", copy_set(SUBMIT, ["plan"], {"method": "profiles", "h": 0.05,
                                                           "profiles": 2}), rid=1)
    for name, raw in [("zero", "0"), ("-1", "-1"), ("37", "37")]:
        add("plan-profiles-%s" % name, obj, ["params", "plan", "profiles"], raw,
            Err(PARAMS, quoted("profiles"), 1, None))
    obj = request("job.submit", copy_set(SUBMIT, ["plan"], {"method": "ot", "h": 0.05,
                                                           "profiles": 2}), rid=1)
    add("plan-profiles-with-ot", obj, ["params", "plan", "profiles"], "2",
        Err(PARAMS, '"plan.profiles" is for the method', 1, None))
    # The plan for the tolerance: its capability in (0, 1], and only with
    # a tolerance (refused before any search).
    tol = copy_set(copy_set(SUBMIT, ["plan"], {"for_tolerance": True, "capability": 0.5}),
                   ["tolerance"], {"rms_nm": {"t": 50}})
    obj = request("job.submit", tol, rid=1)
    for name, raw in [("zero", "0"), ("minus-zero", "-0.0"), ("1.5", "1.5"), ("-1", "-1"),
                      ("1e-400", "1e-400"), ("1e300", "1e300")]:
        add("plan-capability-%s" % name, obj, ["params", "plan", "capability"], raw,
            Err(PARAMS, quoted("plan.capability"), 1, None))
    add("plan-capability-1e400", obj, ["params", "plan", "capability"], "1e400", "parse")
    add("plan-for-tolerance-false", obj, ["params", "plan", "for_tolerance"], "false",
        Err(PARAMS, quoted("plan.for_tolerance") + " must be true", 1, None))
    add("plan-for-tolerance-without-tolerance", request("job.submit", copy_set(tol, ["tolerance"],
                                                                              ABSENT), rid=1),
        ["params", "plan", "capability"], "0.5",
        Err(PARAMS, quoted("tolerance") + " is missing", 1, None))
    # Coordinates of an inline prescription.
    lens = request("job.submit", copy_set(SUBMIT, ["lens"], PRESCRIPTION), rid=1)
    for path, name, raw, code, detail in [
            (["R"], "1e-400", "1e-400", LENS, r'"lens"\.R'),
            (["R"], "minus-zero", "-0.0", LENS, r'"lens"\.R'),
            (["R"], "5e-324", "5e-324", LENS, r'"lens"\.R: .*overflows'),
            (["k"], "1e308", "1e308", LENS, r'"lens"\.k'),
            (["aperture_diameter"], "1e308", "1e308", LENS, r'"lens"\.k: .*aperture'),
            (["aperture_diameter"], "minus-zero", "-0.0", LENS, r'"lens"\.aperture_diameter'),
            (["aperture_diameter"], "-1e-300", "-1e-300", LENS, r'"lens"\.aperture_diameter'),
            (["A", "4"], "3.7e299", "3.7e299", PLAN, "too steep"),
            (["A", "6"], "-1e308", "-1e308", PLAN, "too steep")]:
        add("lens-%s-%s" % (".".join(path), name), lens, ["params", "lens"] + path, raw,
            Err(code, detail, 1, None))
    for path in (["R"], ["A", "4"], ["aperture_diameter"]):
        for name, raw in [("1e400", "1e400"), ("400-digits", "9" * 400)]:
            add("lens-%s-%s" % (".".join(path), name), lens, ["params", "lens"] + path, raw, "parse")
    return cases


# ------------------------------------------------------------ nesting

def nesting_cases():
    cases = []
    deep = 100000

    def add(name, data, answer):
        cases.append(PCase("deep nesting", name, data, [answer], "shared"))

    for name, data in [("array-100000", b"[" * deep + b"]" * deep),
                       ("array-100000-unclosed", b"[" * deep),
                       ("object-100000", b'{"a":' * deep + b"1" + b"}" * deep),
                       ("mixed-100000", b'[{"a":' * (deep // 2)),
                       ("array-2049", b"[" * 2049 + b"]" * 2049)]:
        add(name, data + b"\n", depth_error(data))
    # 2048 levels are allowed: a batch of one element that is not a request.
    add("array-2048", b"[" * 2048 + b"]" * 2048 + b"\n",
        [Err(INVALID, "must be an object", None, None)])
    # Deep values where a scalar belongs.
    for name, path, detail in [("job-id", ["params", "id"], quoted("id")),
                               ("label", ["params", "label"], quoted("label"))]:
        method = "job.get" if name == "job-id" else "job.submit"
        data, _, _ = with_raw(request(method, rid=5000), path, b"[" * 2000 + b"]" * 2000)
        add(name + "-2000", data, Err(PARAMS, detail, 5000, None))
        data, _, _ = with_raw(request(method, rid=5000), path, b"[" * 3000 + b"]" * 3000)
        add(name + "-3000", data, depth_error(data))
    data, _, _ = with_raw(request("version", rid=0), ["id"], b"[" * 500 + b"]" * 500)
    add("request-id-500", data, Err(INVALID, quoted("id"), None, None))
    data, _, _ = with_raw(request("job.submit", rid=5001), ["params", "lens"],
                          b'{"a":' * 1500 + b"1" + b"}" * 1500)
    add("lens-object-1500", data, Err(LENS, r'"lens": missing member "type"', 5001, None))
    data, _, _ = with_raw(request("job.submit", copy_set(SUBMIT, ["lens"], PRESCRIPTION), rid=5002),
                          ["params", "lens", "A", "4"], b"[" * 1500 + b"]" * 1500)
    add("lens-coefficient-1500", data, Err(LENS, r'"lens"\.A\.4', 5002, None))
    data, _, _ = with_raw(request("job.list", rid=5003), ["params", "states"],
                          b"[" * 1000 + b'"queued"' + b"]" * 1000)
    add("states-1000", data, Err(PARAMS, quoted("states") + r"\[0\]", 5003, None))
    return cases


# ------------------------------------------------------------ UTF-8 and NUL

BAD_UTF8 = [
    ("byte-ff", b"\xff"), ("byte-fe", b"\xfe"), ("overlong-slash-2", b"\xc0\xaf"),
    ("overlong-slash-3", b"\xe0\x80\xaf"), ("overlong-slash-4", b"\xf0\x80\x80\xaf"),
    ("overlong-nul", b"\xc0\x80"), ("surrogate-d800", b"\xed\xa0\x80"),
    ("surrogate-dfff", b"\xed\xbf\xbf"), ("surrogate-pair-cesu", b"\xed\xa0\xbd\xed\xb8\x80"),
    ("lone-continuation-80", b"\x80"), ("lone-continuation-bf", b"\xbf"),
    ("truncated-3-byte", b"\xe2\x82"), ("truncated-2-byte", b"\xc3"),
    ("above-10ffff", b"\xf4\x90\x80\x80"), ("five-byte", b"\xf8\x88\x80\x80\x80"),
    ("latin1-e9", b"\xe9t\xe9"),
]
UTF8_PLACES = [
    ("method", request("version", rid=6000), ["method"]),
    ("label", request("job.submit", rid=6000), ["params", "label"]),
    ("client", request("hello", rid=6000), ["params", "client"]),
    ("instrument", request("instrument.status", rid=6000), ["params", "name"]),
]


def utf8_cases():
    cases = []
    for pname, obj, path in UTF8_PLACES:
        value = obj
        for key in path:
            value = value[key]
        for bname, bad in BAD_UTF8:
            raw = b'"' + value[:3].encode() + bad + value[3:].encode() + b'"'
            data, first, last = with_raw(obj, path, raw)
            cases.append(PCase("invalid UTF-8 and NUL", "%s-%s" % (pname, bname), data,
                               [parse_error(data, first, last)], "shared"))
    # In a member name, in the id, in jsonrpc, at the start of the line.
    v = text(request("version", rid=6001))
    for name, data in [("key", v.replace(b'"method"', b'"meth\xffod"')),
                       ("params-key",
                        text(request("job.get", rid=6001)).replace(b'"history"', b'"hist\xc0\xafory"')),
                       ("id-string", v.replace(b"6001", b'"id\xed\xa0\x80"')),
                       ("jsonrpc", v.replace(b'"2.0"', b'"2.\xbf"')),
                       ("utf16-le-bom", ("\ufeff" + v.decode()).encode("utf-16-le")),
                       ("utf16-be", v.decode().encode("utf-16-be")),
                       ("utf32-le", v.decode().encode("utf-32-le"))]:
        bad = next(i for i, b in enumerate(data) if b >= 0x80 or b == 0)
        data += b"\n"
        cases.append(PCase("invalid UTF-8 and NUL", name, data, [parse_error(data, bad, bad + 3, 2)],
                           "shared"))
    # A UTF-8 byte-order mark is skipped at the start of a line (RFC 8259
    # allows it; proto/README.md says so) and refused anywhere else, the
    # column counting it.
    bom = b"\xef\xbb\xbf"
    cases.append(PCase("byte-order mark", "utf8-bom", bom + v + b"\n", [OK], "shared"))
    cases.append(PCase("byte-order mark", "utf8-bom-batch",
                       bom + b"[" + v + b"," + text(request("daemon.status", rid=6004)) + b"]\n",
                       [[OK, OK]], "shared"))
    for name, data, at in [("utf8-bom-twice", bom + bom + v, 3),
                           ("utf8-bom-after-space", b" " + bom + v, 1),
                           ("utf8-bom-inside", v[:-1] + bom + b"}", len(v) - 1)]:
        cases.append(PCase("byte-order mark", name, data + b"\n",
                           [Err(PARSE, r"^column %d: " % column(data, at), None, None)], "shared"))
    # Escapes that are not characters.
    for name, esc in [("escaped-high-surrogate", r"\ud800"), ("escaped-low-surrogate", r"\udfff"),
                      ("escaped-reversed-pair", r"\udc00\ud800"), ("escaped-high-then-letter", r"\ud83dA"),
                      ("escape-too-short", r"\u00e"), ("escape-not-hex", r"\uzzzz"),
                      ("escape-x", r"\x41"), ("escape-unknown", r"\q"),
                      ("raw-tab", "\t"), ("raw-control-01", "\x01"), ("raw-escape-1b", "\x1b")]:
        data, first, last = with_raw(request("hello", rid=6002), ["params", "client"],
                                     ('"ab' + esc + 'zz"').encode())
        cases.append(PCase("invalid UTF-8 and NUL", name, data,
                           [parse_error(data, first, last + 1, 2)], "shared"))
    # A raw NUL byte ends the text for jansson: a parse error.
    v = text(request("version", rid=6003))
    for name, at in [("raw-nul-in-method", v.index(b"version") + 3),
                     ("raw-nul-between-members", v.index(b',"id"')),
                     ("raw-nul-first", 0), ("raw-nul-last", len(v))]:
        data = v[:at] + b"\0" + v[at:] + b"\n"
        cases.append(PCase("invalid UTF-8 and NUL", name, data, [parse_error(data, at, at, 2)], "shared"))
    # Escaped NUL (\u0000) is valid JSON: refused where a name is expected,
    # never cut to a known name.
    nul = "\u0000"

    def contains(name):
        return quoted(name) + " contains a NUL"

    for name, method, path, value, code, detail in [
            ("method", "version", ["method"], "version" + nul, INVALID, "NUL"),
            ("method-only-nul", "version", ["method"], nul, INVALID, "NUL"),
            ("label", "job.submit", ["label"], "cor" + nul + "pus", PARAMS, contains("label")),
            ("client", "hello", ["client"], "x" + nul, PARAMS, contains("client")),
            ("token", "hello", ["token"], nul * 20, PARAMS, contains("token")),
            ("instrument", "job.submit", ["instrument"], INSTRUMENT + nul + "x", PARAMS,
             contains("instrument")),
            ("lens-preset", "job.submit", ["lens"], "strong" + nul + "x", PARAMS, contains("lens")),
            ("plan-method", "job.submit", ["plan", "method"], "ci" + nul, PARAMS, contains("method")),
            ("fit-dof", "job.submit", ["fit", "dof"], "tx" + nul + ",ty", PARAMS, contains("dof")),
            ("fit-residual", "job.submit", ["fit", "residual"], "sag" + nul, PARAMS, contains("residual")),
            ("list-state", "job.list", ["states", 0], "completed" + nul + "x", PARAMS,
             quoted("states") + r"\[0\] contains a NUL"),
            ("list-label", "job.list", ["label"], nul, PARAMS, contains("label")),
            ("subscribe-event", "events.subscribe", ["events", 1], "progress" + nul, PARAMS,
             quoted("events") + r"\[1\] contains a NUL"),
            ("instrument-name", "instrument.status", ["name"], INSTRUMENT + nul, PARAMS, contains("name")),
            ("prescription-name", "job.submit", ["lens"], dict(PRESCRIPTION, name="a" + nul + "b"), LENS,
             '"lens"')]:
        obj = copy_set(request(method, rid=6004), ["params"] + path if path != ["method"] else path, value)
        cases.append(PCase("invalid UTF-8 and NUL", "escaped-nul-" + name, line(obj),
                           [Err(code, detail, 6004, None)], "shared"))
    # A NUL in a member name: jansson refuses it.
    data = b'{"jsonrpc":"2.0","id":6004,"method":"job.get","params":{"id\\u0000":1}}\n'
    cases.append(PCase("invalid UTF-8 and NUL", "escaped-nul-params-key", data,
                       [Err(PARSE, r"^column \d+: ", None, None)], "shared"))
    # An id with NUL comes back whole.
    data = line(request("no.such.method", ABSENT, rid="a\u0000b"))
    cases.append(PCase("invalid UTF-8 and NUL", "escaped-nul-id-echoed", data,
                       [Err(NO_METHOD, "no.such.method", "a\u0000b", None)], "shared"))
    # A name cut in its detail at 64 bytes, inside a character: the detail
    # stays valid UTF-8 (and so is sent at all).
    e, euro, smile = "\u00e9", "\u20ac", "\U0001f600"
    for name, method, path, value, code, detail in [
            ("long-method", None, ["method"], "a" + e * 40, NO_METHOD, 'no method "a' + e),
            ("long-preset", "job.submit", ["params", "lens"], "bb" + euro * 30, LENS,
             'no preset named "bb' + euro),
            ("long-unknown-param", "job.get", ["params", "p" + e * 40], 1, PARAMS,
             'unknown parameter "p' + e),
            ("long-unknown-member", "version", ["x" + smile * 20], 1, INVALID, 'unknown member "x' + smile),
            ("long-unknown-state", "job.list", ["params", "states", 0], "q" + e * 40, PARAMS,
             'unknown value "q' + e)]:
        obj = request(method or "version", ABSENT if method is None else None, rid=6005)
        obj = copy_set(obj, path, value)
        cases.append(PCase("invalid UTF-8 and NUL", "cut-inside-a-character-" + name, line(obj),
                           [Err(code, re.escape(detail), 6005, None)], "shared"))
    return cases


# ------------------------------------------------------------ oversized lines

def _flood(prefix, size, suffix):
    """prefix, filler up to size bytes, suffix: in chunks of 1 MiB."""
    def chunks():
        yield prefix
        left = size - len(prefix)
        block = b"x" * (1 << 20)
        while left > 0:
            n = min(left, len(block))
            yield block[:n]
            left -= n
        yield suffix
    return chunks


def oversized_cases():
    large = Err(TOO_LARGE, "longer than %d bytes" % MAX_REQUEST, None, None)
    cases = []
    # At the limit: parsed (a label too long); one byte more: refused, and
    # the connection goes on.
    head = text(request("job.submit", copy_set(SUBMIT, ["label"], ""), rid=7000))
    at = head.index(b'"label":""') + len(b'"label":"')
    fill = MAX_REQUEST - len(head)
    data = head[:at] + b"l" * fill + head[at:] + b"\n"
    cases.append(PCase("oversized lines", "exactly-max-request-bytes", data,
                       [Err(PARAMS, quoted("label") + " is longer than 256 bytes", 7000, None)], "shared"))
    data = head[:at] + b"l" * (fill + 1) + head[at:] + b"\n" + line(request("version", rid=7001))
    cases.append(PCase("oversized lines", "max-request-bytes-plus-one", data, [large, OK], "shared"))
    data = b" " * (MAX_REQUEST + 1) + b"\n"
    cases.append(PCase("oversized lines", "whitespace-over-the-limit", data, [large], "shared"))
    # 100 MB lines: refused without being kept, the daemon keeps serving,
    # the connection goes on (then the daemon closes it at end of input).
    prefix = head[:at]
    cases.append(PCase("oversized lines", "100MB-label-then-a-request",
                       _flood(prefix, 100 << 20, head[at:] + b"\n" + line(request("version", rid=7002))),
                       [large, OK], "flood"))
    cases.append(PCase("oversized lines", "100MB-without-newline-then-end-of-input",
                       _flood(b'{"jsonrpc":"2.0","id":7003,"method":"', 100 << 20, b""),
                       [large], "flood"))
    return cases


# ------------------------------------------------------------ unknown members

def unknown_member_cases():
    cases = []
    v = request("version", rid=8000)
    for name, key in [("extra", "extra"), ("uppercase-id", "ID"), ("uppercase-method", "Method"),
                      ("params-with-space", "params "), ("empty-name", ""), ("result", "result"),
                      ("error", "error"), ("jsonrpc2", "jsonrpc2"), ("proto", "__proto__"),
                      ("very-long", "k" * 1000), ("unicode", "m\u00e9thode")]:
        obj = dict(v)
        obj[key] = 1
        cases.append(PCase("unknown and duplicate members", "top-level-" + name, line(obj),
                           [Err(INVALID, 'unknown member "%s' % re.escape(key[:64]), 8000, None)], "shared"))
    for method in REQUESTS:
        base = REQUESTS[method]
        params = dict(base) if base is not ABSENT else {}
        params["zz_unknown"] = 1
        cases.append(PCase("unknown and duplicate members", "param-%s" % method,
                           line(request(method, params, rid=8001)),
                           [Err(PARAMS, 'unknown parameter "zz_unknown"', 8001, None)], "shared"))
    for method, typo in [("job.get", "Id"), ("job.submit", "priorty"), ("job.list", "state"),
                         ("events.subscribe", "event"), ("hello", "client_name"), ("queue.stop", "abrt"),
                         ("job.requeue", "reset"), ("queue.move", "pos"),
                         ("instrument.status", "instrument")]:
        params = dict(REQUESTS[method])
        params[typo] = params.pop(next(iter(params)))
        cases.append(PCase("unknown and duplicate members", "typo-%s-%s" % (method, typo),
                           line(request(method, params, rid=8002)),
                           [Err(PARAMS, 'unknown parameter "%s"' % typo, 8002, None)], "shared"))
    for name, path, detail, code in [("plan", ["plan", "x"], 'unknown parameter "x"', PARAMS),
                                     ("plan-density-word", ["plan", "density"],
                                      'unknown parameter "density"', PARAMS),
                                     ("fit", ["fit", "zernikes"], 'unknown parameter "zernikes"', PARAMS),
                                     ("lens-member", ["lens", "radius"], r'"lens".*radius', LENS),
                                     ("lens-coefficient", ["lens", "A", "4x"], r'"lens"\.A\.4x', LENS)]:
        params = copy_set(SUBMIT, ["lens"], PRESCRIPTION) if path[0] == "lens" else SUBMIT
        cases.append(PCase("unknown and duplicate members", "nested-" + name,
                           line(request("job.submit", copy_set(params, path, 1), rid=8003)),
                           [Err(code, detail, 8003, None)], "shared"))
    # Duplicate members: refused by the parser.
    for name, data, key in [
            ("id", b'{"jsonrpc":"2.0","id":1,"id":2,"method":"version"}', b'"id":2'),
            ("method", b'{"jsonrpc":"2.0","id":1,"method":"version","method":"queue.stop"}',
             b'"method":"queue.stop"'),
            ("jsonrpc", b'{"jsonrpc":"2.0","jsonrpc":"2.0","id":1,"method":"version"}',
             b'"jsonrpc":"2.0","id'),
            ("params", b'{"jsonrpc":"2.0","id":1,"method":"job.get","params":{"id":1},"params":{"id":2}}',
             b'"params":{"id":2'),
            ("param-id", b'{"jsonrpc":"2.0","id":1,"method":"job.get","params":{"id":1,"id":2}}', b'"id":2'),
            ("lens-R", b'{"jsonrpc":"2.0","id":1,"method":"job.submit","params":{"lens":{"type":'
                       b'"even_asphere","R":20,"R":-20,"aperture_diameter":10},'
                       b'"plan":{"method":"ci","h":0.3}}}',
             b'"R":-20'),
            ("escaped-same-key", b'{"jsonrpc":"2.0","id":1,"\\u0069d":2,"method":"version"}', b'"\\u0069d"')]:
        at = data.index(key)
        data += b"\n"
        cases.append(PCase("unknown and duplicate members", "duplicate-" + name, data,
                           [Err(PARSE, r"^column \d+: duplicate object key", None,
                                (column(data, at) - 1, column(data, at + len(key)) + 2))], "shared"))
    return cases


# ------------------------------------------------------------ NaN

NAN_TOKENS = [("NaN", "NaN"), ("minus-NaN", "-NaN"), ("nan", "nan"), ("Infinity", "Infinity"),
              ("minus-Infinity", "-Infinity"), ("plus-Infinity", "+Infinity"), ("inf", "inf"),
              ("INF", "INF")]
BAD_NUMBERS = [("hex", "0x10"), ("hex-float", "0x1p3"), ("leading-plus", "+1"), ("bare-dot", ".5"),
               ("trailing-dot", "1."), ("leading-zero", "017"), ("bare-minus", "-"),
               ("bare-exponent", "1e"), ("double-minus", "--1"), ("comma-decimal", "1,5")]


def nan_cases():
    cases = []

    def plan(method, density):
        return request("job.submit", copy_set(SUBMIT, ["plan"], {"method": method, density: 1}))
    lens = request("job.submit", copy_set(SUBMIT, ["lens"], PRESCRIPTION), rid=1)
    coords = [("lens-R", lens, ["params", "lens", "R"]), ("lens-k", lens, ["params", "lens", "k"]),
              ("lens-A4", lens, ["params", "lens", "A", "4"]),
              ("lens-aperture", lens, ["params", "lens", "aperture_diameter"]),
              ("plan-h", request("job.submit", rid=1), ["params", "plan", "h"]),
              ("plan-spacing", plan("raster", "spacing"), ["params", "plan", "spacing"]),
              ("plan-points", plan("fermat", "points"), ["params", "plan", "points"]),
              ("qbfs-a1", request("job.submit", copy_set(SUBMIT, ["lens"], QBFS), rid=1),
               ["params", "lens", "a", 1]),
              ("qbfs-norm-radius", request("job.submit", copy_set(SUBMIT, ["lens"], QBFS), rid=1),
               ["params", "lens", "norm_radius"])]
    others = [("priority", request("job.submit", rid=1), ["params", "priority"]),
              ("job-id", request("job.get", rid=1), ["params", "id"]),
              ("request-id", request("version", rid=1), ["id"]),
              ("list-limit", request("job.list", rid=1), ["params", "limit"]),
              ("list-offset", request("job.list", rid=1), ["params", "offset"]),
              ("list-uid", request("job.list", rid=1), ["params", "uid"]),
              ("zernike", request("job.submit", rid=1), ["params", "fit", "zernike"]),
              ("position", request("queue.move", rid=1), ["params", "position"]),
              ("subscribe-job", request("events.subscribe", rid=1), ["params", "job"])]

    def add(name, obj, path, raw):
        data, first, last = with_raw(obj, path, raw)
        # jansson names the column where the token ends: the bad character,
        # or the last of a token it could not read as a number.
        cases.append(PCase("NaN, Infinity, malformed numbers", name, data,
                           [parse_error(data, first, last + 2, 1)], "shared"))

    for pname, obj, path in coords:
        for tname, tok in NAN_TOKENS + [("1e999", "1e999"), ("minus-1e999", "-1e999")]:
            add("%s-%s" % (pname, tname), obj, path, tok)
    for pname, obj, path in others:
        for tname, tok in [("NaN", "NaN"), ("Infinity", "Infinity"), ("minus-Infinity", "-Infinity")]:
            add("%s-%s" % (pname, tname), obj, path, tok)
    for tname, tok in BAD_NUMBERS:
        add("plan-h-" + tname, coords[4][1], coords[4][2], tok)
        add("lens-R-" + tname, lens, ["params", "lens", "R"], tok)
    # The words as strings: the wrong type, named.
    for pname, obj, path, code, detail in [
            ("lens-R", lens, ["params", "lens", "R"], LENS, r'"lens"\.R'),
            ("lens-A4", lens, ["params", "lens", "A", "4"], LENS, r'"lens"\.A\.4'),
            ("lens-aperture", lens, ["params", "lens", "aperture_diameter"], LENS,
             r'"lens"\.aperture_diameter'),
            ("qbfs-a1", coords[7][1], coords[7][2], LENS, r'"lens"\.a'),
            ("qbfs-norm-radius", coords[8][1], coords[8][2], LENS, r'"lens"\.norm_radius'),
            ("plan-h", coords[4][1], coords[4][2], PARAMS, quoted("h")),
            ("plan-points", coords[6][1], coords[6][2], PARAMS, quoted("points")),
            ("priority", others[0][1], others[0][2], PARAMS, quoted("priority"))]:
        for word in ("NaN", "-Infinity"):
            if pname == "lens-R" and word == "-Infinity":
                continue    # a plane: R "infinity" (docs/prescriptions.md)
            cases.append(PCase("NaN, Infinity, malformed numbers", "%s-string-%s" % (pname, word),
                               line(copy_set(obj, path, word)), [Err(code, detail, 1, None)], "shared"))
    return cases


# ------------------------------------------------------------ batches

def batch_cases():
    cases = []
    e_obj = Err(INVALID, "must be an object", None, None)

    def add(name, data, answers):
        cases.append(PCase("batches and notifications", name, data, answers, "shared"))

    add("empty-batch", b"[]\n", [Err(INVALID, "an empty batch", None, None)])
    add("empty-batch-with-spaces", b"[ \t ]\n", [Err(INVALID, "an empty batch", None, None)])
    add("batch-of-a-number", b"[1]\n", [[e_obj]])
    add("batch-of-scalars", b'[1,"a",null,true,1.5]\n', [[e_obj] * 5])
    add("batch-of-empty-objects", b"[{},{}]\n", [[Err(INVALID, quoted("jsonrpc"), None, None)] * 2])
    add("nested-batch", b"[" + text([request("version", rid=9000)]) + b"]\n", [[e_obj]])
    add("batch-mixed", text([request("version", rid=9001), request("no.such", ABSENT, rid=9002),
                             {"jsonrpc": "2.0", "method": "version"}, 5,
                             request("job.get", {"id": "one"}, rid=9003)]) + b"\n",
        [[OK, Err(NO_METHOD, "no.such", 9002, None), e_obj, Err(PARAMS, quoted("id"), 9003, None)]])
    add("batch-duplicate-ids", text([request("job.get", {"id": -1}, rid=9004)] * 3) + b"\n",
        [[Err(PARAMS, quoted("id"), 9004, None)] * 3])
    add("batch-of-wrong-types", text([request("job.list", {"limit": 0}, rid=9005),
                                      request("queue.stop", {"abort": "yes"}, rid=9006)]) + b"\n",
        [[Err(PARAMS, quoted("limit"), 9005, None), Err(PARAMS, quoted("abort"), 9006, None)]])
    data = b"[" + text(request("version", rid=9007)) + b","
    add("batch-truncated", data + b"\n", [end_error(data)])
    data = b"[1,]"
    add("batch-trailing-comma", data + b"\n", [parse_error(data, 3, 3)])
    data = b"[1 2]"
    add("batch-missing-comma", data + b"\n", [parse_error(data, 3, 3)])
    # Notifications are never answered, also when they are wrong; but a
    # message that is not a valid request is answered with id null.
    add("notification-unknown-method", line({"jsonrpc": "2.0", "method": "no.such"}), [])
    add("notification-wrong-type", line({"jsonrpc": "2.0", "method": "job.get", "params": {"id": "x"}}), [])
    add("notification-unknown-param", line({"jsonrpc": "2.0", "method": "version", "params": {"x": 1}}), [])
    add("batch-of-bad-notifications",
        text([{"jsonrpc": "2.0", "method": "no.such"},
              {"jsonrpc": "2.0", "method": "queue.stop", "params": {"abort": 1}}]) + b"\n", [])
    add("notification-with-old-jsonrpc", line({"jsonrpc": "1.0", "method": "version"}),
        [Err(INVALID, quoted("jsonrpc"), None, None)])
    add("notification-with-unknown-member", line({"jsonrpc": "2.0", "method": "version", "x": 1}),
        [Err(INVALID, 'unknown member "x"', None, None)])
    # The batch limit: MAX_BATCH elements are answered, one more is not.
    add("batch-at-the-limit", b"[" + b",".join([b"7"] * MAX_BATCH) + b"]\n", [[e_obj] * MAX_BATCH])
    add("batch-over-the-limit", b"[" + b",".join([b"7"] * (MAX_BATCH + 1)) + b"]\n",
        [Err(INVALID, "more than %d" % MAX_BATCH, None, None)])
    # A line of the largest size, all batch elements: one refusal, not
    # half a million answers (hundreds of MB).
    n = (MAX_REQUEST - 2) // 2
    add("batch-of-half-a-million", b"[" + b",".join([b"1"] * n) + b"]\n",
        [Err(INVALID, "a batch of %d requests" % n, None, None)])
    n = (MAX_REQUEST - 2) // 3
    add("batch-of-empty-objects-over-the-limit", b"[" + b",".join([b"{}"] * n) + b"]\n",
        [Err(INVALID, "more than %d" % MAX_BATCH, None, None)])
    return cases


# ------------------------------------------------------------ blank lines

def blank_cases():
    cases = []
    for name, data in [("empty-line", b"\n"), ("crlf", b"\r\n"), ("space", b" \n"), ("tab", b"\t\n"),
                       ("mixed-whitespace", b" \t \t  \r\n"), ("1000-spaces", b" " * 1000 + b"\n"),
                       ("two-carriage-returns", b"\r\r\n"), ("vertical-tab", b"\x0b\n"),
                       ("form-feed", b"\x0c\n"), ("no-break-space", b"\xc2\xa0\n"),
                       ("ideographic-space", "\u3000".encode() + b"\n")]:
        body = data[:-1]
        if body.endswith(b"\r"):
            body = body[:-1]
        cases.append(PCase("empty and blank lines", name, data, [end_error(body + b"\n")], "shared"))
    cases.append(PCase("empty and blank lines", "three-empty-lines", b"\n\n\n",
                       [end_error(b"\n")] * 3, "shared"))
    return cases


# ------------------------------------------------------------ garbage

def garbage_lines(blob):
    """Expected answers to a blob of bytes: one parse error per line."""
    answers = []
    for part in blob.split(b"\n")[:-1]:
        body = part[:-1] if part.endswith(b"\r") else part
        answers.append(Err(PARSE, r"^column \d+: ", None, None))
        try:
            json.loads(body.decode("utf-8"), parse_constant=lambda c: 1 / 0)
            raise AssertionError("garbage that parses: %r" % body[:40])
        except (ValueError, ZeroDivisionError):
            pass
    return answers


def garbage_cases():
    cases = []
    rng = random.Random(90210)
    for size in [1, 2, 3, 7, 16, 64, 255, 1000, 4096, 65536]:
        for kind in ("any", "high"):
            lo = 0x80 if kind == "high" else 0
            blob = bytes(b for b in (rng.randrange(lo, 256) for _ in range(size * 2)) if b != 0x0a)[:size]
            if blob[:1] in (b" ", b"\t", b"\r", b"[", b"{", b'"') or blob[:1].isdigit() or blob[:1] == b"-":
                blob = b"\xff" + blob[1:]
            blob += b"\n"
            cases.append(PCase("binary garbage", "random-%s-%d" % (kind, size), blob,
                               garbage_lines(blob), "shared"))
    client_hello = bytes.fromhex(
        "16030100c8010000c40303" + "5f" * 32 + "20" + "a7" * 32 + "0020c02bc02fc02cc030cca9cca8c013c014"
        "009c009d002f0035000a01000079000000140012000f61737068642e6578616d706c65")
    for name, blob in [
            ("http-get", b"GET /asphd HTTP/1.1\r\nHost: localhost\r\nAccept: */*\r\n\r\n"),
            ("http-post-json",
             b"POST / HTTP/1.1\r\nContent-Type: application/json\r\nContent-Length: 45\r\n\r\n" +
             text(request("version", rid=1)) + b"x\n"),
            ("tls-client-hello", client_hello + b"\n"),
            ("ssh-banner", b"SSH-2.0-OpenSSH_9.2p1 Debian-2\r\n"),
            ("redis-ping", b"*1\r\n$4\r\nPING\r\n"),
            ("gzip-magic", bytes.fromhex("1f8b0800000000000003") + b"\xcb\x48\xcd\xc9\xc9\x07\x00\n"),
            ("png-header", bytes.fromhex("89504e470d0a1a0a0000000d49484452")),
            ("elf-header", b"\x7fELF\x02\x01\x01" + bytes(9) + b"\x03\x00\x3e\x00\n"),
            ("msgpack-request", b"\x84\xa7jsonrpc\xa32.0\xa2id\x01\xa6method\xa7version\xa6params\x80\n"),
            ("all-zero-bytes", bytes(64) + b"\n"), ("all-ff-bytes", b"\xff" * 64 + b"\n"),
            ("xml", b'<?xml version="1.0"?><methodCall><methodName>version</methodName></methodCall>\n'),
            ("yaml", b"jsonrpc: '2.0'\n"),
            ("python-dict", b"{'jsonrpc': '2.0', 'id': 1, 'method': 'version'}\n"),
            ("json5-comment", b'{"jsonrpc":"2.0","id":1,"method":"version"} // why\n'),
            ("two-objects-one-line", text(request("version", rid=1)) * 2 + b"\n"),
            ("object-then-garbage", text(request("version", rid=1)) + b"\x00\xff\n"),
            ("escape-sequences", b"\x1b[2J\x1b[H\x1b]0;asphd\x07\n"),
            ("ctrl-c-ctrl-d", b"\x03\x04\n")]:
        if not blob.endswith(b"\n"):
            blob += b"\n"
        cases.append(PCase("binary garbage", name, blob, garbage_lines(blob), "shared"))
    return cases


# ------------------------------------------------------------ split writes

def split_cases():
    cases = []
    bad_type = line(request("job.get", {"id": "9"}, rid=9500))
    cases.append(PCase("split writes", "one-byte-per-write",
                       [bad_type[i:i + 1] for i in range(len(bad_type))],
                       [Err(PARAMS, quoted("id"), 9500, None)], "shared"))
    broken = b'{"jsonrpc":"2.0","id":9501,"method":"version",}\n'
    cases.append(PCase("split writes", "one-byte-per-write-malformed",
                       [broken[i:i + 1] for i in range(len(broken))],
                       [parse_error(broken, broken.index(b",}") + 1, broken.index(b",}") + 1)], "shared"))
    long_label = line(request("job.submit", copy_set(SUBMIT, ["label"], "\u00e9" * 150), rid=9502))
    parts, at = [], 0
    for i, b in enumerate(long_label):
        if b == 0xc3:   # cut between the two bytes of each é
            parts.append(long_label[at:i + 1])
            at = i + 1
    parts.append(long_label[at:])
    cases.append(PCase("split writes", "cut-inside-every-character", parts,
                       [Err(PARAMS, quoted("label") + " is longer than 256 bytes", 9502, None)], "shared"))
    bad = b'{"jsonrpc":"2.0","id":9503,"method":"ver\xe2\x82\xffsion"}\n'
    i = bad.index(b"\xe2")
    cases.append(PCase("split writes", "invalid-utf8-across-writes",
                       [bad[:i], bad[i:i + 1], bad[i + 1:i + 2], bad[i + 2:]],
                       [parse_error(bad, i, i + 2, 2)], "shared"))
    cr = line(request("queue.stop", {"abort": "no"}, rid=9504))[:-1]
    cases.append(PCase("split writes", "crlf-across-writes", [cr + b"\r", b"\n"],
                       [Err(PARAMS, quoted("abort"), 9504, None)], "shared"))
    three = (line(request("job.get", {"id": 0}, rid=9505)) + line(request("nope", ABSENT, rid=9506)) +
             b"{]\n")
    cases.append(PCase("split writes", "three-requests-one-write", three,
                       [Err(PARAMS, quoted("id"), 9505, None), Err(NO_METHOD, "nope", 9506, None),
                        parse_error(b"{]\n", 1, 1)], "shared"))
    a = line(request("job.list", {"limit": -5}, rid=9507))
    b = line(request("job.result", {"id": "x"}, rid=9508))
    cases.append(PCase("split writes", "request-and-a-half", [a + b[:20], b[20:]],
                       [Err(PARAMS, quoted("limit"), 9507, None), Err(PARAMS, quoted("id"), 9508, None)],
                       "shared"))
    spaces = [b" "] * 2000 + [b"\n"]
    cases.append(PCase("split writes", "2000-writes-of-a-space", spaces, [end_error(b" " * 2000 + b"\n")],
                       "shared"))
    deep = b"[" * 3000 + b"\n"
    cases.append(PCase("split writes", "deep-nesting-in-100-writes",
                       [deep[i:i + 30] for i in range(0, len(deep), 30)],
                       [depth_error(deep)], "shared"))
    over = b"y" * (MAX_REQUEST + 10) + b"\n" + line(request("job.get", {"id": 1.5}, rid=9509))
    cases.append(PCase("split writes", "oversized-line-in-64k-writes",
                       [over[i:i + 65536] for i in range(0, len(over), 65536)],
                       [Err(TOO_LARGE, "longer than %d bytes" % MAX_REQUEST, None, None),
                        Err(PARAMS, quoted("id"), 9509, None)], "shared"))
    # An incomplete request that never ends: -32003, then closed.
    cases.append(PCase("split writes", "stalled-inside-a-request", b'{"jsonrpc":"2.0","id":9510,"meth',
                       [Err(TIMEOUT, "waited too long", None, None)], "stall"))
    return cases


def all_cases():
    return (truncation_cases() + wrong_type_cases() + huge_number_cases() + nesting_cases() +
            utf8_cases() + oversized_cases() + unknown_member_cases() + nan_cases() + batch_cases() +
            blank_cases() + garbage_cases() + split_cases())
