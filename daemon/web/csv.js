// SPDX-License-Identifier: GPL-3.0-or-later
// CSV as the page exports it (RFC 4180): a cell with a comma, a quote or a
// line break is quoted; a text cell that a spreadsheet would take for a
// formula (it starts with = + - @, a tab or a carriage return: OWASP's
// "CSV injection") starts with a ' so that it shows as the text it is.
// Numbers are written as they are (a negative one is no formula).

export function csvCell(v) {
  if (v === null || v === undefined) return "";
  let s = String(v);
  if (typeof v === "string" && /^[=+\-@\t\r]/.test(s)) s = "'" + s;
  return /[",\r\n]/.test(s) ? `"${s.replace(/"/g, '""')}"` : s;
}

export function csvText(cols, rows) {
  return [cols.join(","), ...rows.map((r) => cols.map((c) => csvCell(r[c])).join(","))].join("\n") + "\n";
}
