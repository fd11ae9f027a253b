#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""A man page from docs/NAME.S.md: md2man.py GO_MD2MAN IN OUT VERSION.

The page's first line, "# NAME(S)", becomes the title go-md2man turns into
.TH (NAME S "" "asphd VERSION" "User Commands"); the rest goes through
go-md2man as it is. Its output is then mended where go-md2man 2.0.2
(Debian 12) makes roff that renders badly:
- its .nh (no hyphenation) comes before .TH, which turns hyphenation back
  on, and paths and option names get split ("/var/lib/as-phd");
- a table cell it wraps in a text block (T{ ... T}) ends with a newline
  where tbl wants the tab of the next cell, so the rest of the row moves
  to a row of its own;
- its tables never wrap: the longest cells run past the right margin. The
  widest column is marked x (it takes the width left) and its cells are
  text blocks, which tbl fills to that width.
"""
import re
import subprocess
import sys

MANUALS = {"1": "User Commands", "8": "System Administration"}


def title(markdown, version):
    first, _, rest = markdown.partition("\n")
    m = re.fullmatch(r"# ([a-z][a-z0-9-]*)\(([1-8])\)", first)
    if not m:
        sys.exit(f"md2man.py: the first line must be '# NAME(SECTION)', not {first!r}")
    name, section = m.groups()
    return f'# {name} {section} "" "asphd {version}" "{MANUALS[section]}"\n{rest}'


def cells(data):
    """The rows of a tbl data section as lists of cell texts."""
    rows, row, i = [], [], 0
    while i < len(data):
        if data.startswith("T{\n", i):
            end = data.index("\nT}", i)
            row.append(data[i + 3:end])
            i = end + 3
            if data.startswith("\n\t", i):      # the stray newline
                i += 1
        else:
            j = i
            while j < len(data) and data[j] not in "\t\n":
                j += 1
            row.append(data[i:j])
            i = j
        if i >= len(data) or data[i] == "\n":
            rows.append(row)
            row = []
        i += 1
    return rows


def visible(cell):
    return len(re.sub(r"\\f[A-Z]|\\&", "", cell))


def table(block):
    """One .TS ... .TE block, rewritten."""
    lines = block.split("\n")
    options = lines[1]
    n_format = next(i for i, line in enumerate(lines) if line.rstrip().endswith("."))
    rows = cells("\n".join(lines[n_format + 1:-1]))
    ncol = max(len(r) for r in rows)
    rows = [r + [""] * (ncol - len(r)) for r in rows]
    widths = [sum(visible(r[c]) for r in rows[1:]) for c in range(ncol)]
    wide = widths.index(max(widths))
    spec = " ".join("lx" if c == wide else "l" for c in range(ncol))
    out = [".TS", options, spec + " ."]
    for k, r in enumerate(rows):
        out.append("\t".join(f"T{{\n{cell}\nT}}" if k and c == wide and cell else cell
                             for c, cell in enumerate(r)))
    out.append(".TE")
    return "\n".join(out)


def mend(roff):
    roff = re.sub(r"\A\.nh\n(\.TH [^\n]*\n)", r"\1.nh\n", roff)
    # A text line that go-md2man's wrap starts with "'" is a control line to
    # troff (the no-break form); it emits no such macro itself.
    roff = re.sub(r"^'", r"\\&'", roff, flags=re.M)
    return re.sub(r"^\.TS\n.*?\n\.TE$", lambda m: table(m.group(0)), roff,
                  flags=re.M | re.S)


def main():
    go_md2man, src, dst, version = sys.argv[1:]
    with open(src, encoding="utf-8") as f:
        markdown = title(f.read(), version)
    roff = subprocess.run([go_md2man], input=markdown, capture_output=True, text=True,
                          check=True).stdout
    with open(dst, "w", encoding="utf-8") as f:
        f.write(mend(roff))


if __name__ == "__main__":
    main()
