# SPDX-License-Identifier: GPL-3.0-or-later
"""The bad-input corpus: malformed prescriptions, OpticStudio lens files,
points files (delimited text, PLY, JSON, X3P, SDF, Zygo MetroPro .dat and
.datx), instrument and daemon configurations and
recorded scans, generated
from a valid template of each by mutations (truncation, wrong types, huge
numbers, deep nesting, invalid UTF-8, very long lines, unknown members, NaN
coordinates, flipped bytes) plus cases that break one rule of the format.

Each case is a Case(kind, name, data, field): data is the file's bytes (or a
function making them, for the large ones); field, when set, is the field the
error must name. What a kind is fed to and what it must answer is in
test-badinput.py. Everything is deterministic: the same cases every run.
"""
import json
import os
import random
import io
import struct
import zipfile
from collections import namedtuple

Case = namedtuple("Case", "kind name data field")

HERE = os.path.dirname(os.path.abspath(__file__))
SCAN_TEMPLATE = os.path.join(HERE, "..", "fuzz", "corpus", "scanfile", "strong-ci.scan")
CORPUS = os.path.join(HERE, "..", "fuzz", "corpus")

PRESCRIPTION = {
    "type": "even_asphere", "name": "strong", "R": 20.097, "k": -1,
    "A": {"4": -2.0868e-5, "6": -3.9031e-9, "8": 3.4102e-11}, "aperture_diameter": 40,
}
INSTRUMENTS = {"instruments": [{
    "name": "bench",
    "stage": {"driver": "mock", "options": {"speed": 35, "kinematics": "r-theta-z"}},
    "probe": {"driver": "mock", "options": {"probe": "tactile", "tip_radius": 1.0}},
}]}
DAEMON = {
    "socket_mode": "0660",
    "limits": {"max_clients": 64, "max_queue": 100},
    "instruments": INSTRUMENTS["instruments"],
}
POINTS_JSON = {
    "points": [[0.731, -1.29, 0.0417], [2.6, 0.37, -0.112], [-1.9, 2.03, 0.2283]],
    "triangles": [[2, 0, 1]],
}


def dumps(doc, indent=1):
    return json.dumps(doc, indent=indent).encode()


# ------------------------------------------------------------ JSON mutations

def _set(doc, path, value):
    """A deep copy of doc with the member at path (a list of keys and
    indices) replaced by value."""
    doc = json.loads(json.dumps(doc))
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return doc


def _field(path):
    return ".".join(str(k) for k in path)


def _with_raw(doc, path, raw):
    """doc as text with the value at path replaced by raw JSON text (which
    may be invalid JSON: NaN, 1e400, ...)."""
    marker = "@@RAW@@"
    text = json.dumps(_set(doc, path, marker), indent=1)
    return text.replace('"' + marker + '"', raw).encode("utf-8", "surrogateescape")


def json_syntax_cases(kind, doc, string_path, line_comments=False):
    """Mutations any JSON reader must refuse: the text is not JSON, or not
    the object the format wants. string_path names a string member (for
    invalid UTF-8 and very long strings). line_comments: the format takes
    // comments to the end of a line (the daemon's configuration,
    docs/daemon.md), so such a comment is no bad input there, but other
    comments are, and so is one that comments out the rest of a line the
    object needs."""
    text = dumps(doc)
    cases = [
        Case(kind, "empty", b"", None),
        Case(kind, "blank", b" \n\t\n", None),
        Case(kind, "not-an-object-array", b"[]", None),
        Case(kind, "not-an-object-number", b"42\n", None),
        Case(kind, "not-an-object-string", b'"text"', None),
        Case(kind, "not-an-object-null", b"null", None),
        Case(kind, "trailing-garbage", text + b"x", None),
        Case(kind, "second-object", text + text, None),
        Case(kind, "byte-order-mark", b"\xef\xbb\xbf" + text, None),
        Case(kind, "nul-byte", text[:len(text) // 2] + b"\0" + text[len(text) // 2:], None),
    ] + ([
        Case(kind, "block-comment", b"/* a comment */\n" + text, None),
        Case(kind, "hash-comment", b"# a comment\n" + text, None),
        Case(kind, "comment-hides-the-object", b"{ // " + dumps(doc, None)[1:], None),
    ] if line_comments else [
        Case(kind, "comment", b"// a comment\n" + text, None),
    ]) + [
        Case(kind, "single-quotes", text.replace(b'"', b"'"), None),
        Case(kind, "latin1-file", text.replace(b"{", b"{\"\xe9t\xe9\": 1, ", 1), None),
        Case(kind, "utf16", text.decode().encode("utf-16"), None),
        Case(kind, "deep-array-nesting", b"[" * 100000 + b"]" * 100000, None),
        Case(kind, "deep-object-nesting", b'{"a":' * 5000 + b"1" + b"}" * 5000, None),
        Case(kind, "unterminated-string", text[:text.index(b'"') + 3], None),
        Case(kind, "control-char-in-string", _with_raw(doc, string_path, '"a\x01b"'), None),
        Case(kind, "invalid-utf8-value", _with_raw(doc, string_path, '"ab\udcffcd"'), None),
        Case(kind, "overlong-utf8", dumps(doc).replace(b'"', b'"\xc0\xaf', 1), None),
        Case(kind, "utf8-surrogate", dumps(doc).replace(b'"', b'"\xed\xa0\x80', 1), None),
        Case(kind, "truncated-utf8", dumps(doc).replace(b'"', b'"\xe2\x82', 1), None),
        Case(kind, "invalid-escape", _with_raw(doc, string_path, '"a\\qb"'), None),
        Case(kind, "lone-surrogate-escape", _with_raw(doc, string_path, '"\\udc00"'), None),
        Case(kind, "very-long-line",
             lambda: b"{" + b" " * (8 << 20) + b'"x": [' + b"1," * (1 << 20) + b"]", None),
        Case(kind, "huge-unterminated-string", lambda: b'{"' + b"a" * (16 << 20), None),
    ]
    for i in range(1, 10):
        cut = len(text) * i // 10
        cases.append(Case(kind, "truncated-%d0pct" % i, text[:cut], None))
    return cases


def json_value_cases(kind, doc, number_paths, strict, unknown_paths=()):
    """Wrong types and impossible numbers in each numeric member; unknown
    and duplicate members where the format refuses them (strict)."""
    cases = []
    for path in number_paths:
        f = _field(path)
        for name, raw in [("nan", "NaN"), ("infinity", "Infinity"), ("minus-infinity", "-Infinity"),
                          ("overflow", "1e400"), ("minus-overflow", "-1e400"),
                          ("integer-overflow", "184467440737095516160"),
                          ("hex", "0x10"), ("leading-plus", "+1"), ("bare-dot", ".5")]:
            cases.append(Case(kind, "%s-%s" % (f, name), _with_raw(doc, path, raw), None))
        for name, value in [("string", "12.5"), ("array", [1.5]), ("object", {"v": 1.5}),
                            ("null", None), ("bool", True)]:
            cases.append(Case(kind, "%s-%s" % (f, name), dumps(_set(doc, path, value)), f))
    if strict:
        for path in unknown_paths:
            parent = path[:-1]
            node = json.loads(json.dumps(doc))
            for key in parent:
                node = node[key]
            node[path[-1]] = 1
            cases.append(Case(kind, "unknown-member-" + _field(path),
                              dumps(_set(doc, parent, node) if parent else node), None))
        first = next(iter(doc))
        text = dumps(doc, indent=None)
        dup = text.replace(b"{", b'{"%s": %s, ' % (first.encode(), json.dumps(doc[first]).encode()), 1)
        cases.append(Case(kind, "duplicate-member", dup, None))
    return cases


# ------------------------------------------------------------ prescriptions

def prescription_cases():
    k = "prescription"
    p = PRESCRIPTION
    cases = json_syntax_cases(k, p, ["name"])
    cases += json_value_cases(k, p, [["R"], ["k"], ["aperture_diameter"], ["A", "4"], ["A", "8"]],
                              True, [["radius"], ["A", "4x"], ["Aperture_diameter"], [""]])

    def without(*keys):
        return dumps({m: v for m, v in p.items() if m not in keys})

    cases += [
        Case(k, "type-unknown", dumps(_set(p, ["type"], "toroid")), "type"),
        Case(k, "type-number", dumps(_set(p, ["type"], 3)), "type"),
        Case(k, "name-number", dumps(_set(p, ["name"], 5)), "name"),
        Case(k, "R-zero", dumps(_set(p, ["R"], 0)), "R"),
        Case(k, "aperture-zero", dumps(_set(p, ["aperture_diameter"], 0)), "aperture_diameter"),
        Case(k, "aperture-negative", dumps(_set(p, ["aperture_diameter"], -40)), "aperture_diameter"),
        Case(k, "aperture-tiny-negative", dumps(_set(p, ["aperture_diameter"], -5e-324)), "aperture_diameter"),
        Case(k, "A-odd-power", dumps(_set(p, ["A", "3"], 1e-5)), "A.3"),
        Case(k, "A-power-22", dumps(_set(p, ["A", "22"], 1e-5)), "A.22"),
        Case(k, "A-power-0", dumps(_set(p, ["A", "0"], 1e-5)), "A.0"),
        Case(k, "A-power-negative", dumps(_set(p, ["A", "-2"], 1e-5)), "A.-2"),
        Case(k, "A-power-word", dumps(_set(p, ["A", "four"], 1e-5)), "A.four"),
        Case(k, "A-power-huge", dumps(_set(p, ["A", "99999999999999999999"], 1e-5)), None),
        Case(k, "A-array", dumps(_set(p, ["A"], [1e-5, 2e-7])), "A"),
        Case(k, "missing-type", without("type"), None),
        Case(k, "missing-R", without("R"), None),
        Case(k, "missing-aperture", without("aperture_diameter"), None),
        Case(k, "only-type", dumps({"type": "even_asphere"}), None),
        Case(k, "empty-object", b"{}", None),
        # The conic's square root goes negative inside the aperture.
        Case(k, "sag-undefined", dumps({"type": "even_asphere", "R": 10, "k": 0,
                                        "aperture_diameter": 30}), "k"),
        Case(k, "sag-undefined-hyperbola", dumps({"type": "even_asphere", "R": 5, "k": 3,
                                                  "aperture_diameter": 8}), "k"),
        Case(k, "very-large-file", lambda: dumps(_set(p, ["name"], "n" * (3 << 20))), None),
    ]
    return cases


# ------------------------------------------------------------ lens files

ZMX = """UNIT MM X W X CM MR CPMM
SURF 0
  CURV 0.0
  DISZ INFINITY
SURF 1
  TYPE QED_TYPE
  CURV 8.712E-02 0 0 0 0 ""
  XDAT 1 0 0 0 1.0 0.0 0 ""
  XDAT 2 3 0 0 1.0 0.0 0 ""
  XDAT 3 13.5 0 0 1.0 0.0 0 ""
  XDAT 4 -0.2913 0 0 1.0 0.0 0 ""
  XDAT 5 -0.0871 0 0 1.0 0.0 0 ""
  XDAT 6 0.0231 0 0 1.0 0.0 0 ""
  CONI -0.5873
  DIAM 12.2 1 0 0 1 ""
SURF 2
  TYPE EVENASPH
  CURV -1.25E-002 0 0 0 0 ""
  PARM 2 3.1E-007
  CONI -1.05
  DIAM 30 0 0 0 1 ""
  SQAP 15 10 0
  OBDC 0 22
"""


def zmx_cases():
    """OpticStudio .zmx files broken where a reader could misread them:
    asph lens import FILE --surface 1 refuses each, naming the keyword
    (the field) and where."""
    k = "lens-zmx"
    good = ZMX.encode()

    def sub(old, new, count=1):
        assert old in ZMX, old
        return ZMX.replace(old, new, count).encode()

    utf16 = b"\xff\xfe" + ZMX.replace("\n", "\r\n").encode("utf-16-le")
    return [
        Case(k, "empty", b"", None),
        Case(k, "no-surf", b"NAME x\nUNIT MM\n", None),
        Case(k, "utf16-odd-length", utf16[:-1], None),
        Case(k, "utf16-lone-surrogate", utf16[:40] + b"\x00\xd8" + utf16[40:], None),
        Case(k, "utf16-without-bom", ZMX.encode("utf-16-le"), None),
        Case(k, "nul-byte", good[:60] + b"\0" + good[60:], None),
        Case(k, "unit-feet", sub("UNIT MM", "UNIT FT"), "UNIT"),
        Case(k, "surf-number-fraction", sub("SURF 1", "SURF 1.5"), "SURF"),
        Case(k, "surf-number-huge", sub("SURF 1", "SURF 99999999999999999999"), "SURF"),
        Case(k, "surf-twice", sub("SURF 2", "SURF 1"), "SURF"),
        Case(k, "curv-without-value", sub("  CURV 8.712E-02 0 0 0 0 \"\"", "  CURV"), "CURV"),
        Case(k, "curv-not-a-number", sub("8.712E-02", "8.712E-0x2"), "CURV"),
        Case(k, "curv-nan", sub("8.712E-02", "nan"), "CURV"),
        Case(k, "curv-overflow", sub("8.712E-02", "1e400"), "CURV"),
        Case(k, "coni-infinite", sub("CONI -0.5873", "CONI inf"), "CONI"),
        Case(k, "xdat-index-0", sub("XDAT 1 0", "XDAT 0 0"), "XDAT"),
        Case(k, "xdat-index-251", sub("XDAT 6 0.0231", "XDAT 251 0.0231"), "XDAT"),
        Case(k, "xdat-index-fraction", sub("XDAT 6 0.0231", "XDAT 6.5 0.0231"), "XDAT"),
        Case(k, "xdat-without-value", sub("XDAT 6 0.0231 0 0 1.0 0.0 0 \"\"", "XDAT 6"), "XDAT"),
        Case(k, "q-type-2", sub("XDAT 1 0 0", "XDAT 1 2 0"), "XDAT 1"),
        Case(k, "q-terms-fraction", sub("XDAT 2 3 0", "XDAT 2 2.5 0"), "XDAT 2"),
        Case(k, "q-terms-negative", sub("XDAT 2 3 0", "XDAT 2 -1 0"), "XDAT 2"),
        Case(k, "q-term-31", ZMX.replace("XDAT 2 3 0", "XDAT 2 40 0").replace(
            "  CONI -0.5873", "  XDAT 40 1e-6\n  CONI -0.5873").encode(), "XDAT"),
        Case(k, "q-norm-radius-zero", sub("XDAT 3 13.5", "XDAT 3 0"), "XDAT 3"),
        Case(k, "q-parameter", sub("  CONI -0.5873", "  PARM 2 1e-5\n  CONI -0.5873"), "PARM 2"),
        Case(k, "type-unknown", sub("TYPE QED_TYPE", "TYPE GRID_SAG"), "TYPE"),
        Case(k, "type-without-name", sub("TYPE QED_TYPE", "TYPE"), "TYPE"),
        Case(k, "conic-root-in-aperture", sub("CONI -0.5873", "CONI 2.5"), "CONI"),
        Case(k, "diam-negative", sub("DIAM 12.2 1", "DIAM -12.2 1"), "DIAM"),
        Case(k, "diam-missing", sub("  DIAM 12.2 1 0 0 1 \"\"\n", ""), "DIAM"),
        Case(k, "clap-hole", sub("  DIAM 12.2", "  CLAP 2 12\n  DIAM 12.2"), "CLAP"),
        Case(k, "two-apertures", sub("  DIAM 12.2", "  CLAP 0 12\n  ELAP 6 5\n  DIAM 12.2"), "ELAP"),
        Case(k, "user-aperture", sub("  DIAM 12.2", "  UDAD 0 0\n  DIAM 12.2"), "UDAD"),
        Case(k, "sqap-zero-height", sub("  DIAM 12.2", "  SQAP 6 0\n  DIAM 12.2"), "SQAP"),
        Case(k, "sqap-without-height", sub("  DIAM 12.2", "  SQAP 6\n  DIAM 12.2"), "SQAP"),
        Case(k, "obdc-not-a-number", sub("  DIAM 12.2", "  CLAP 0 6\n  OBDC 0 x\n  DIAM 12.2"), "OBDC"),
        Case(k, "very-long-line", sub("CONI -0.5873", "CONI -0." + "5" * 100000 + "x"), "CONI"),
        Case(k, "huge-file", lambda: good + b"NOTE " + b"x" * (17 << 20) + b"\n", None),
    ]


# ------------------------------------------------------------ points

def csv_cases():
    k = "points-csv"
    good = b"x,y,z\n0.731,-1.29,0.0417\n2.6,0.37,-0.112\n-1.9,2.03,0.2283\n"
    rows = [
        ("nan-x", b"nan,-1.29,0.0417", "x"), ("nan-y", b"0.731,NaN,0.0417", "y"),
        ("nan-z", b"0.731,-1.29,-nan", "z"), ("inf-x", b"inf,-1.29,0.0417", "x"),
        ("infinity-y", b"0.731,Infinity,0.0417", "y"), ("minus-inf-z", b"0.731,-1.29,-inf", "z"),
        ("overflow-x", b"1e999,-1.29,0.0417", "x"), ("overflow-z", b"0.731,-1.29,-1e400", "z"),
        ("word", b"0.731,abc,0.0417", "y"), ("empty-field", b"0.731,,0.0417", "y"),
        ("blank-field", b"0.731,   ,0.0417", "y"), ("two-numbers", b"0.731,1 2,0.0417", "y"),
        ("comma-decimal", b"0,731,-1.29,0.0417", None), ("short-row", b"0.731,-1.29", None),
        ("long-row", b"0.731,-1.29,0.0417,5", None), ("one-field", b"0.731", None),
        ("semicolons", b"0.731;-1.29;0.0417", None), ("tabs", b"0.731\t-1.29\t0.0417", None),
        ("quoted-text", b'"0.731 mm",-1.29,0.0417', "x"),
        ("quoted-comma-decimal", b'"0,731",-1.29,0.0417', "x"),
        ("quote-unclosed", b'"0.731,-1.29,0.0417', None),
        ("text-after-quote", b'"0.731"5,-1.29,0.0417', None), ("unicode-minus", "\u22121.29,0.5,0.25".encode(), "x"),
        ("invalid-utf8", b"0.731,\xff\xfe,0.0417", "y"), ("nul-in-row", b"0.731,-1.\x0029,0.0417", None),
        ("value-too-long", b"0.731," + b"1" * 200 + b",0.0417", "y"),
        ("trailing-comma", b"0.731,-1.29,0.0417,", None), ("units", b"0.731mm,-1.29,0.0417", "x"),
        ("percent", b"0.731,-1.29,5%", "z"), ("binary", bytes(range(1, 32)) + b",1,2", None),
    ]
    cases = []
    for name, row, field in rows:
        cases.append(Case(k, name, good + row + b"\n", field))
        cases.append(Case(k, name + "-first-row", b"x,y,z\n" + row + b"\n", field))
    cases += [
        Case(k, "empty", b"", None),
        Case(k, "comments-only", b"# nothing\n\n# here\n", None),
        Case(k, "header-without-z", b"x,y\n0.731,-1.29\n", None),
        Case(k, "header-quote-unclosed", good.replace(b"x,y,z", b'"x","y","z'), None),
        Case(k, "header-semicolons", good.replace(b"x,y,z", b"x;y;z"), None),
        Case(k, "header-invalid-utf8", b"x,\xc3,z\n1,2,3\n", None),
        Case(k, "header-nul", b"x,y\0,z\n1,2,3\n", None),
        Case(k, "ply-as-csv", b"ply\nformat ascii 1.0\nend_header\n", None),
        Case(k, "no-header-two-columns", b"0.731 -1.29\n2.6 0.37\n", None),
        Case(k, "no-header-four-columns", b"0.731;-1.29;0.0417;5\n", None),
        Case(k, "unnamed-header", b"Pos X;Pos Y;Height\n0,731;-1,29;0,0417\n", None),
        Case(k, "unit-unknown", b"x [mm],y [mm],z [furlong]\n1,2,3\n", "z furlong"),
        Case(k, "decimal-comma-and-point", b"x;y;z\n1,234.5;2;3\n", "x"),
        Case(k, "decimal-comma-twice", b"x;y;z\n1,2,3;2;3\n", "x"),
        Case(k, "preamble-then-bad-row", b"Instrument: X\nDate: today\n1 2 abc\n", None),
        Case(k, "two-x-columns", b"x,y,z,X\n1,2,3,4\n", "X"),
        Case(k, "units-overflow", b"x [m],y,z\n1e306,2,3\n", "x"),
        Case(k, "very-long-line", lambda: good + b"1" * (12 << 20) + b",2,3\n", None),
        Case(k, "very-long-header", lambda: b"x,y,z," + b"w" * (12 << 20) + b"\n1,2,3\n", None),
        Case(k, "many-columns", lambda: b"x,y,z\n" + b"1," * (1 << 20) + b"1\n", None),
        Case(k, "nan-after-many-rows",
             lambda: b"x,y,z\n" + b"0.5,0.25,0.125\n" * 200000 + b"1,2,nan\n", "z"),
    ]
    return cases


PLY_HEAD = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
            b"property double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n")
PLY_BODY = b"0.731 -1.29 0.0417\n2.6 0.37 -0.112\n-1.9 2.03 0.2283\n3 2 0 1\n"


def _binary_ply(count=3, verts=None, face=(3, 2, 0, 1), header_extra=b""):
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty double x\n"
            b"property double y\nproperty double z\nelement face 1\n"
            b"property list uchar int vertex_indices\n" % count) + header_extra + b"end_header\n"
    verts = verts if verts is not None else [(0.731, -1.29, 0.0417), (2.6, 0.37, -0.112),
                                             (-1.9, 2.03, 0.2283)]
    body = b"".join(struct.pack("<3d", *v) for v in verts)
    return head + body + struct.pack("<B3i", *face)


def ply_cases():
    k = "points-ply"
    good = PLY_HEAD + PLY_BODY
    nan = float("nan")
    cases = [
        Case(k, "empty", b"", None),
        Case(k, "no-magic", good[4:], None),
        Case(k, "magic-uppercase", b"PLY" + good[3:], None),
        Case(k, "no-end-header", PLY_HEAD.replace(b"end_header\n", b""), None),
        Case(k, "no-end-header-with-body", PLY_HEAD.replace(b"end_header\n", b"") + PLY_BODY, None),
        Case(k, "format-big-endian", good.replace(b"ascii", b"binary_big_endian"), "format"),
        Case(k, "format-unknown", good.replace(b"ascii", b"utf8"), "format"),
        Case(k, "count-negative", good.replace(b"vertex 3", b"vertex -3"), "element"),
        Case(k, "count-word", good.replace(b"vertex 3", b"vertex three"), "element"),
        Case(k, "count-missing", good.replace(b"vertex 3", b"vertex"), "element"),
        Case(k, "count-huge", good.replace(b"vertex 3", b"vertex 99999999999999999999"), "element"),
        Case(k, "count-over-limit", good.replace(b"vertex 3", b"vertex 268435457"), "element"),
        Case(k, "count-beyond-data", good.replace(b"vertex 3", b"vertex 200000000"), "element"),
        Case(k, "faces-beyond-data", good.replace(b"face 1", b"face 100000000"), "element"),
        Case(k, "element-unknown", good.replace(b"end_header", b"element edge 2\nend_header"), "edge"),
        Case(k, "property-type-unknown", good.replace(b"double y", b"quad y"), "y"),
        Case(k, "property-incomplete", good.replace(b"double y", b"double"), None),
        Case(k, "too-many-properties",
             good.replace(b"element face", b"property float w\n" * 40 + b"element face"), None),
        Case(k, "no-z", good.replace(b"property double z\n", b""), None),
        Case(k, "face-not-a-list", good.replace(b"list uchar int vertex_indices", b"int vertex_indices"), None),
        Case(k, "face-list-type-unknown", good.replace(b"list uchar int", b"list byte int"), None),
        Case(k, "faces-before-vertices",
             b"ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
             b"element vertex 3\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
             b"3 2 0 1\n" + PLY_BODY[:-8], None),
        Case(k, "header-line-too-long", good.replace(b"comment", b"comment") .replace(
            b"end_header", b"comment " + b"c" * 400 + b"\nend_header"), None),
        Case(k, "header-unknown-keyword", good.replace(b"end_header", b"vertex_data 3\nend_header"), None),
        Case(k, "header-invalid-utf8", good.replace(b"end_header", b"\xff\xfe\nend_header"), None),
        Case(k, "body-short", PLY_HEAD + PLY_BODY[:30], None),
        Case(k, "body-missing-face", PLY_HEAD + PLY_BODY[:-8], None),
        Case(k, "body-nan", PLY_HEAD + PLY_BODY.replace(b"0.37", b"nan"), "y"),
        Case(k, "body-inf", PLY_HEAD + PLY_BODY.replace(b"-0.112", b"-inf"), "z"),
        Case(k, "body-overflow", PLY_HEAD + PLY_BODY.replace(b"2.6", b"1e400"), "x"),
        Case(k, "body-word", PLY_HEAD + PLY_BODY.replace(b"2.6", b"two"), "x"),
        Case(k, "body-long-number", PLY_HEAD + PLY_BODY.replace(b"2.6", b"2." + b"6" * 100), "x"),
        Case(k, "body-invalid-utf8", PLY_HEAD + PLY_BODY.replace(b"2.6", b"\xc3\x28"), "x"),
        Case(k, "body-nul", PLY_HEAD + PLY_BODY.replace(b"0.37", b"0.3\0"), None),
        Case(k, "body-extra-vertex", PLY_HEAD.replace(b"element face 1\nproperty list uchar int vertex_indices\n", b"")
             .replace(b"vertex 3", b"vertex 2") + PLY_BODY[:-8], "element"),
        Case(k, "body-extra-face", PLY_HEAD + PLY_BODY + b"3 0 1 2\n", "element"),
        Case(k, "binary-trailing-bytes", _binary_ply() + b"\0\0\0\0", "element"),
        Case(k, "face-quad", PLY_HEAD + PLY_BODY.replace(b"3 2 0 1", b"4 2 0 1 1"), None),
        Case(k, "face-index-out-of-range", PLY_HEAD + PLY_BODY.replace(b"3 2 0 1", b"3 2 0 3"), None),
        Case(k, "face-index-negative", PLY_HEAD + PLY_BODY.replace(b"3 2 0 1", b"3 2 -1 1"), None),
        Case(k, "face-index-fraction", PLY_HEAD + PLY_BODY.replace(b"3 2 0 1", b"3 2 0.5 1"), None),
        Case(k, "face-index-nan", PLY_HEAD + PLY_BODY.replace(b"3 2 0 1", b"3 2 nan 1"), None),
        Case(k, "binary-end-header-at-eof", _binary_ply().split(b"end_header\n")[0] + b"end_header", None),
        Case(k, "binary-truncated-vertex", _binary_ply()[:-40], None),
        Case(k, "binary-truncated-face", _binary_ply()[:-5], None),
        Case(k, "binary-nan", _binary_ply(verts=[(0.5, nan, 0.25), (1, 2, 3), (4, 5, 6)]), "y"),
        Case(k, "binary-inf", _binary_ply(verts=[(0.5, 1, 0.25), (float("inf"), 2, 3), (4, 5, 6)]), "x"),
        Case(k, "binary-face-index-out-of-range", _binary_ply(face=(3, 2, 0, 7)), None),
        Case(k, "binary-face-index-negative", _binary_ply(face=(3, 2, -1, 1)), None),
        Case(k, "binary-face-quad", _binary_ply(face=(4, 2, 0, 1)), None),
        Case(k, "binary-count-beyond-data", _binary_ply(count=1 << 27), "element"),
        Case(k, "very-long-body-line", lambda: PLY_HEAD + b" " * (12 << 20) + PLY_BODY + b"x", None),
    ]
    return cases


def points_json_cases():
    k = "points-json"
    p = POINTS_JSON
    cases = json_syntax_cases(k, p, ["points", 0])
    cases += [
        Case(k, "points-missing", dumps({"triangles": []}), "points"),
        Case(k, "points-object", dumps(_set(p, ["points"], {"0": [1, 2, 3]})), "points"),
        Case(k, "points-string", dumps(_set(p, ["points"], "1,2,3")), "points"),
        Case(k, "point-two-coordinates", dumps(_set(p, ["points", 1], [2.6, 0.37])), "points[1]"),
        Case(k, "point-four-coordinates", dumps(_set(p, ["points", 1], [2.6, 0.37, 1, 2])), "points[1]"),
        Case(k, "point-number", dumps(_set(p, ["points", 2], 1.5)), "points[2]"),
        Case(k, "point-object", dumps(_set(p, ["points", 0], {"x": 1, "y": 2, "z": 3})), "points[0]"),
        Case(k, "coordinate-string", dumps(_set(p, ["points", 1, 2], "-0.112")), "points[1]"),
        Case(k, "coordinate-null", dumps(_set(p, ["points", 0, 0], None)), "points[0]"),
        Case(k, "coordinate-bool", dumps(_set(p, ["points", 2, 1], False)), "points[2]"),
        Case(k, "coordinate-nan", _with_raw(p, ["points", 1, 0], "NaN"), None),
        Case(k, "coordinate-infinity", _with_raw(p, ["points", 1, 0], "Infinity"), None),
        Case(k, "coordinate-overflow", _with_raw(p, ["points", 1, 0], "1e400"), None),
        Case(k, "coordinate-int-overflow", _with_raw(p, ["points", 1, 0], "99999999999999999999999"), None),
        Case(k, "triangle-index-out-of-range", dumps(_set(p, ["triangles", 0, 1], 3)), "triangles[0]"),
        Case(k, "triangle-index-negative", dumps(_set(p, ["triangles", 0, 1], -1)), "triangles[0]"),
        Case(k, "triangle-index-real", dumps(_set(p, ["triangles", 0, 1], 1.0)), "triangles[0]"),
        Case(k, "triangle-index-huge", dumps(_set(p, ["triangles", 0, 1], 4294967296)), "triangles[0]"),
        Case(k, "triangle-two-indices", dumps(_set(p, ["triangles", 0], [0, 1])), "triangles[0]"),
        Case(k, "values-short", dumps(dict(p, values=[1.5, 2.5])), "values"),
        Case(k, "values-string", dumps(dict(p, values=[1.5, "2.5", 3.5])), "values"),
        Case(k, "very-many-points-last-bad",
             lambda: dumps({"points": [[0.5, 0.25, 0.125]] * 300000 + [[1, 2]]}, indent=None),
             "points[300000]"),
    ]
    return cases


# ------------------------------------------------------------ configurations

def instrument_cases():
    k = "instrument"
    c = INSTRUMENTS
    cases = json_syntax_cases(k, c, ["instruments", 0, "name"])
    cases += json_value_cases(k, c, [["instruments", 0, "stage", "options", "speed"],
                                     ["instruments", 0, "probe", "options", "tip_radius"]],
                              True, [["instrument"], ["instruments", 0, "stages"],
                                     ["instruments", 0, "stage", "option"]])
    inst = c["instruments"][0]
    cases += [
        Case(k, "instruments-empty", dumps({"instruments": []}), "instruments"),
        Case(k, "instruments-object", dumps({"instruments": inst}), "instruments"),
        Case(k, "instruments-missing", b"{}", "instruments"),
        Case(k, "instrument-string", dumps({"instruments": ["mock"]}), None),
        Case(k, "stage-missing", dumps({"instruments": [{"probe": inst["probe"]}]}), None),
        Case(k, "probe-missing", dumps({"instruments": [{"stage": inst["stage"]}]}), None),
        Case(k, "driver-unknown", dumps(_set(c, ["instruments", 0, "stage", "driver"], "nosuch")), None),
        Case(k, "driver-number", dumps(_set(c, ["instruments", 0, "probe", "driver"], 7)), None),
        Case(k, "driver-path", dumps(_set(c, ["instruments", 0, "probe", "driver"], "../../tmp/x")), None),
        Case(k, "driver-missing", dumps(_set(c, ["instruments", 0, "stage"], {"options": {}})), None),
        Case(k, "options-array", dumps(_set(c, ["instruments", 0, "stage", "options"], [1])), None),
        Case(k, "option-unknown", dumps(_set(c, ["instruments", 0, "probe", "options", "sped"], 3)), None),
        Case(k, "option-negative-speed", dumps(_set(c, ["instruments", 0, "stage", "options", "speed"], -35)), None),
        Case(k, "option-zero-speed", dumps(_set(c, ["instruments", 0, "stage", "options", "speed"], 0)), None),
        Case(k, "option-bad-choice", dumps(_set(c, ["instruments", 0, "stage", "options", "kinematics"], "hexapod")), None),
        Case(k, "option-bad-probe", dumps(_set(c, ["instruments", 0, "probe", "options", "probe"], "laser")), None),
        Case(k, "option-bool-as-string", dumps(_set(c, ["instruments", 0, "stage", "options", "stream"], "yes")), None),
        Case(k, "option-int-fraction", dumps(_set(c, ["instruments", 0, "probe", "options", "seed"], 1.5)), None),
        Case(k, "option-int-negative", dumps(_set(c, ["instruments", 0, "probe", "options", "fail_after"], -1)), None),
        Case(k, "option-rate-string", dumps(_set(c, ["instruments", 0, "probe", "options", "rate"], "fast")), None),
        Case(k, "name-duplicate", dumps({"instruments": [inst, inst]}), None),
        Case(k, "name-number", dumps(_set(c, ["instruments", 0, "name"], 12)), None),
        Case(k, "name-too-long", dumps(_set(c, ["instruments", 0, "name"], "n" * 300)), None),
    ]
    return cases


def daemon_cases():
    k = "daemon"
    d = DAEMON
    cases = json_syntax_cases(k, d, ["socket_mode"], line_comments=True)
    cases += json_value_cases(k, d, [["limits", "max_clients"], ["limits", "max_queue"]],
                              True, [["limitz"], ["limits", "max_client"], ["instruments", 0, "extra"]])
    cases += [
        Case(k, "socket-mode-world-writable", dumps(_set(d, ["socket_mode"], "0666")), None),
        Case(k, "socket-mode-word", dumps(_set(d, ["socket_mode"], "rw-rw----")), None),
        Case(k, "socket-mode-number", dumps(_set(d, ["socket_mode"], 660)), None),
        Case(k, "max-clients-zero", dumps(_set(d, ["limits", "max_clients"], 0)), None),
        Case(k, "max-clients-negative", dumps(_set(d, ["limits", "max_clients"], -1)), None),
        Case(k, "max-clients-huge", dumps(_set(d, ["limits", "max_clients"], 1 << 40)), None),
        Case(k, "limits-array", dumps(_set(d, ["limits"], [64])), None),
        Case(k, "instrument-driver-unknown",
             dumps(_set(d, ["instruments", 0, "stage", "driver"], "nosuch")), None),
        Case(k, "instrument-option-range",
             dumps(_set(d, ["instruments", 0, "stage", "options", "speed"], -3)), None),
        Case(k, "operator-group-missing", dumps(dict(d, operator_group="no-such-group-asph")), None),
    ]
    return cases


# ------------------------------------------------------------ recorded scans

def scan_cases():
    """Damaged copies of a real recording. Every byte of a scan is under a
    checksum, so each change must be found: the header refused, or the
    reading stopped at the damaged block with a report."""
    k = "scan"
    with open(SCAN_TEMPLATE, "rb") as f:
        good = f.read()
    hlen = struct.unpack_from("<I", good, 12)[0]
    body = 20 + hlen
    cases = [Case(k, "empty", b"", None), Case(k, "zeros", bytes(4096), None),
             Case(k, "text", b"ASPHSCAN is what this is not\n", None),
             Case(k, "magic-only", good[:8], None),
             Case(k, "bad-magic", b"ASPHSCAM" + good[8:], None),
             Case(k, "major-version-99", good[:8] + struct.pack("<H", 99) + good[10:], None),
             Case(k, "header-length-zero", good[:12] + struct.pack("<I", 0) + good[16:], None),
             Case(k, "header-length-huge", good[:12] + struct.pack("<I", 0xFFFFFFFF) + good[16:], None),
             Case(k, "header-length-over-limit", good[:12] + struct.pack("<I", (1 << 20) + 1) + good[16:], None),
             Case(k, "header-length-beyond-file", good[:12] + struct.pack("<I", len(good)) + good[16:], None),
             Case(k, "garbage-after-end", good + b"\0" * 3 + b"garbage", None),
             Case(k, "two-scans", good + good, None),
             Case(k, "points-csv", b"x,y,z\n1,2,3\n", None)]
    rng = random.Random(9)
    cases.append(Case(k, "random-bytes", bytes(rng.randrange(256) for _ in range(3000)), None))
    cases.append(Case(k, "random-after-header", good[:body] + bytes(rng.randrange(256) for _ in range(900)), None))
    # Truncations: inside the file header, inside the header JSON, inside
    # each block.
    for cut in [1, 7, 11, 15, 19, 20, 21, body // 2, body - 1] + list(range(body + 1, len(good), 29)):
        cases.append(Case(k, "truncated-at-%d" % cut, good[:cut], None))
    # One flipped bit at offsets spread over the whole file.
    for off in [0, 9, 13, 17, 25, body // 3, body - 2] + list(range(body, len(good), 23)):
        bad = bytearray(good)
        bad[off] ^= 1 << (off % 8)
        cases.append(Case(k, "bit-flip-at-%d" % off, bytes(bad), None))
    return cases


# ------------------------------------------------------------ measured maps

def _seed(kind, name):
    with open(os.path.join(CORPUS, kind, name), "rb") as f:
        return f.read()


def _damage(k, good, cuts, flips):
    """Truncations and single flipped bits of a binary template."""
    cases = [Case(k, "truncated-at-%d" % c, good[:c], None) for c in cuts if c < len(good)]
    for off in flips:
        if off < len(good):
            bad = bytearray(good)
            bad[off] ^= 1 << (off % 8)
            cases.append(Case(k, "bit-flip-at-%d" % off, bytes(bad), None))
    return cases


def _x3p(xml, members=None, checksum=True):
    """An X3P container: main.xml and the members, md5checksum.hex of it."""
    import hashlib
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("main.xml", xml)
        for name, data in (members or {}).items():
            z.writestr(name, data)
        if checksum:
            z.writestr("md5checksum.hex", hashlib.md5(xml).hexdigest() + " *main.xml\n")
    return out.getvalue()


X3P_MAIN = (b'<?xml version="1.0" encoding="UTF-8"?>\n'
            b'<p:ISO5436_2 xmlns:p="http://www.opengps.eu/2008/ISO5436_2"><Record1>'
            b'<Revision>ISO5436 - 2000</Revision><FeatureType>SUR</FeatureType><Axes>'
            b'<CX><AxisType>I</AxisType><Increment>1e-6</Increment><Offset>0</Offset></CX>'
            b'<CY><AxisType>I</AxisType><Increment>1e-6</Increment><Offset>0</Offset></CY>'
            b'<CZ><AxisType>A</AxisType><DataType>D</DataType></CZ></Axes></Record1>'
            b'<Record3><MatrixDimension><SizeX>2</SizeX><SizeY>2</SizeY><SizeZ>1</SizeZ>'
            b'</MatrixDimension><DataLink><PointDataLink>bindata/data.bin</PointDataLink>'
            b'<MD5ChecksumPointData>@MD5@</MD5ChecksumPointData></DataLink></Record3>'
            b'<Record4><ChecksumFile>md5checksum.hex</ChecksumFile></Record4></p:ISO5436_2>')


def _x3p_matrix(xml=X3P_MAIN, data=None, **kw):
    import hashlib
    data = struct.pack("<4d", 1e-7, 2e-7, float("nan"), 4e-7) if data is None else data
    xml = xml.replace(b"@MD5@", hashlib.md5(data).hexdigest().encode())
    return _x3p(xml, {"bindata/data.bin": data}, **kw)


def x3p_cases():
    k = "points-x3p"
    seed = _seed(k, "float.x3p")
    cases = [
        Case(k, "empty", b"", None),
        Case(k, "zip-magic-only", b"PK\x03\x04", None),
        Case(k, "main-xml-missing", _x3p_matrix().replace(b"main.xml", b"mainxxml"), None),
        Case(k, "xml-not-well-formed", _x3p(X3P_MAIN[:-20]), None),
        Case(k, "root-wrong", _x3p(b"<root/>"), None),
        Case(k, "md5-data-wrong", _x3p(X3P_MAIN.replace(b"@MD5@", b"0" * 32),
                                       {"bindata/data.bin": struct.pack("<4d", 1, 2, 3, 4)}), None),
        Case(k, "data-short", _x3p_matrix(data=struct.pack("<3d", 1e-7, 2e-7, 3e-7)), None),
        Case(k, "data-member-missing", _x3p(X3P_MAIN.replace(b"@MD5@", b"0" * 32)), None),
        Case(k, "axis-type-wrong", _x3p_matrix(X3P_MAIN.replace(b"<AxisType>I</AxisType><Increment>1e-6</Increment><Offset>0</Offset></CX>",
                                                                b"<AxisType>Q</AxisType></CX>")), None),
        Case(k, "z-incremental", _x3p_matrix(X3P_MAIN.replace(b"<AxisType>A</AxisType><DataType>D",
                                                              b"<AxisType>I</AxisType><DataType>D")), None),
        Case(k, "data-type-wrong", _x3p_matrix(X3P_MAIN.replace(b"<DataType>D", b"<DataType>X")), None),
        Case(k, "increment-word", _x3p_matrix(X3P_MAIN.replace(b"1e-6</Increment><Offset>0</Offset></CX>",
                                                               b"one</Increment><Offset>0</Offset></CX>")), None),
        Case(k, "size-zero", _x3p_matrix(X3P_MAIN.replace(b"<SizeX>2", b"<SizeX>0")), None),
        Case(k, "size-huge", _x3p_matrix(X3P_MAIN.replace(b"<SizeX>2", b"<SizeX>99999999999")), None),
        Case(k, "size-beyond-data", _x3p_matrix(X3P_MAIN.replace(b"<SizeY>2", b"<SizeY>20000")), None),
        Case(k, "all-invalid", _x3p_matrix(data=struct.pack("<4d", *[float("nan")] * 4)), None),
        Case(k, "no-dimension", _x3p_matrix(X3P_MAIN.replace(b"MatrixDimension", b"Dimension")), None),
        Case(k, "datum-text", _x3p(X3P_MAIN.replace(b"<DataLink><PointDataLink>bindata/data.bin</PointDataLink>"
                                                    b"<MD5ChecksumPointData>@MD5@</MD5ChecksumPointData></DataLink>",
                                                    b"<DataList><Datum>1</Datum><Datum>x</Datum><Datum>3</Datum>"
                                                    b"<Datum>4</Datum></DataList>")), None),
        Case(k, "datum-too-many", _x3p(X3P_MAIN.replace(b"<DataLink><PointDataLink>bindata/data.bin</PointDataLink>"
                                                        b"<MD5ChecksumPointData>@MD5@</MD5ChecksumPointData></DataLink>",
                                                        b"<DataList>" + b"<Datum>1</Datum>" * 5 + b"</DataList>")), None),
        Case(k, "entity-expansion", _x3p(b'<?xml version="1.0"?><!DOCTYPE r [<!ENTITY a "aaaaaaaaaa">'
                                         b'<!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">'
                                         b'<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">]>'
                                         b'<r>&c;&c;&c;</r>'), None),
        Case(k, "external-entity", _x3p(b'<?xml version="1.0"?><!DOCTYPE r [<!ENTITY e SYSTEM "file:///etc/passwd">]>'
                                        b'<r>&e;</r>'), None),
        Case(k, "text-file", b"x,y,z\n" + b"PK", None),
    ]
    cases.append(Case(k, "md5checksum-wrong", _x3p_with_sum(X3P_MAIN, "0" * 32), None))
    cases.append(Case(k, "no-md5checksum-data-bad", _x3p_matrix(data=b"\0" * 31, checksum=False), None))
    return cases + _damage(k, seed, [5, 30, 100, len(seed) // 2, len(seed) - 1],
                           list(range(0, len(seed), max(1, len(seed) // 40))))


def _x3p_with_sum(xml, digest):
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        z.writestr("main.xml", xml)
        z.writestr("md5checksum.hex", digest + " *main.xml\n")
    return out.getvalue()


SDF_ASCII = (b"aBCR-1.0\nManufacID   = Lab\nCreateDate  = 010320241000\nModDate     = 010320241000\n"
             b"NumPoints   = 3\nNumProfiles = 2\nXscale      = 2.0E-06\nYscale      = 4.0E-06\n"
             b"Zscale      = 1.0E-09\nZresolution = -1\nCompression = 0\nDataType    = 5\n"
             b"CheckType   = 0\n*\n10 -20 30\n40 50 -60\n*\n")


def sdf_cases():
    k = "points-sdf"
    binary = _seed(k, "b.sdf")
    a = SDF_ASCII
    cases = [
        Case(k, "version-only", b"aBCR-1.0\n", None),
        Case(k, "no-star", a.replace(b"CheckType   = 0\n*\n", b"CheckType   = 0\n"), None),
        Case(k, "points-zero", a.replace(b"NumPoints   = 3", b"NumPoints   = 0"), None),
        Case(k, "points-word", a.replace(b"NumPoints   = 3", b"NumPoints   = three"), "NumPoints"),
        Case(k, "points-negative", a.replace(b"NumPoints   = 3", b"NumPoints   = -3"), "NumPoints"),
        Case(k, "points-huge", a.replace(b"NumPoints   = 3", b"NumPoints   = 1e300"), "NumPoints"),
        Case(k, "points-beyond-data", a.replace(b"NumProfiles = 2", b"NumProfiles = 60000"), None),
        Case(k, "xscale-zero", a.replace(b"2.0E-06", b"0"), None),
        Case(k, "zscale-nan", a.replace(b"1.0E-09", b"nan"), "Zscale"),
        Case(k, "datatype-unknown", a.replace(b"DataType    = 5", b"DataType    = 12"), "DataType"),
        Case(k, "compressed", a.replace(b"Compression = 0", b"Compression = 1"), "Compression"),
        Case(k, "checksum", a.replace(b"CheckType   = 0", b"CheckType   = 1"), "CheckType"),
        Case(k, "key-missing", a.replace(b"Zscale      = 1.0E-09\n", b""), None),
        Case(k, "line-not-key", a.replace(b"Zresolution = -1", b"Zresolution -1"), None),
        Case(k, "values-short", a.replace(b"40 50 -60", b"40 50"), None),
        Case(k, "values-long", a.replace(b"40 50 -60", b"40 50 -60 70"), None),
        Case(k, "value-word", a.replace(b"-20", b"minus"), None),
        Case(k, "value-inf", a.replace(b"-20", b"inf"), None),
        Case(k, "nul", a.replace(b"-20", b"-2\0"), None),
        Case(k, "binary-short-header", binary[:50], None),
        Case(k, "binary-datatype", binary[:79] + b"\x0c" + binary[80:], "DataType"),
        Case(k, "binary-scale-zero", binary[:46] + struct.pack("<d", 0) + binary[54:], None),
        Case(k, "binary-count-beyond-data", binary[:42] + struct.pack("<HH", 65535, 65535) + binary[46:], None),
        Case(k, "binary-all-nan", binary[:81] + struct.pack("<4f", *[float("nan")] * 4), None),
    ]
    return cases + _damage(k, binary, [8, 45, 80, 90], [])


def metropro_cases():
    k = "points-metropro"
    good = _seed(k, "f1.dat")

    def put(off, fmt, v, base=good):
        return base[:off] + struct.pack(fmt, v) + base[off + struct.calcsize(fmt):]

    cases = [
        Case(k, "magic-only", good[:4], None),
        Case(k, "header-short", good[:500], None),
        Case(k, "format-wrong", put(4, ">H", 3), "header_format"),
        Case(k, "size-wrong", put(6, ">I", 4096), "header_size"),
        Case(k, "format3-short", put(6, ">I", 4096, put(4, ">H", 3, put(0, ">I", 0x881B0371))), None),
        Case(k, "phase-res-unknown", put(218, ">H", 9), "phase_res"),
        Case(k, "intensity-size-wrong", put(60, ">I", 7), "ac_n_bytes"),
        Case(k, "phase-size-wrong", put(72, ">I", 7), "cn_n_bytes"),
        Case(k, "phase-huge", put(70, ">H", 65535, put(72, ">I", 3 * 65535 * 4)), None),
        Case(k, "no-phase", put(68, ">H", 0), "cn_width"),
        Case(k, "lateral-zero", put(184, ">f", 0.0), "lateral_res"),
        Case(k, "lateral-nan", put(184, ">f", float("nan")), "lateral_res"),
        Case(k, "wavelength-zero", put(168, ">f", 0.0), "wavelength_in"),
        Case(k, "all-invalid", good[:len(good) - 24] + struct.pack(">6i", *[2147483647] * 6), None),
    ]
    return cases + _damage(k, good, [10, 100, 833, len(good) - 1], list(range(0, 240, 7)))


def datx_cases():
    k = "points-datx"
    good = _seed(k, "nm1.datx")
    cases = [Case(k, "signature-only", b"\x89HDF\r\n\x1a\n", None),
             Case(k, "signature-zeros", b"\x89HDF\r\n\x1a\n" + bytes(2000), None)]
    rng = random.Random(29)
    cases.append(Case(k, "random-after-signature", good[:8] + bytes(rng.randrange(256) for _ in range(3000)), None))
    return cases + _damage(k, good, [100, 1000, len(good) // 2, len(good) - 100], [])


def all_cases():
    return (prescription_cases() + zmx_cases() + csv_cases() + ply_cases() + points_json_cases() +
            x3p_cases() + sdf_cases() + metropro_cases() + datx_cases() +
            instrument_cases() + daemon_cases() + scan_cases())
