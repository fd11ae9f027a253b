// SPDX-License-Identifier: GPL-3.0-or-later
// A quantity as people read it: the one rule of lib/util/quantity.h
// (quantity_format) over the rows of its table, which names.js carries
// from the C table. The text output and the report print by the same rule:
// one value, one sign, one precision everywhere.
import { quantities, QUANTITY_MAX_FIXED } from "./names.js";

export const UNIT = 1;          // followed by the unit: "-0.74 nm"
export const NO_SIGN = 2;       // an uncertainty or a limit: no '+'

const byPath = new Map(quantities.map((q) => [q.path, q]));
const byVerdict = new Map(quantities.filter((q) => q.verdict).map((q) => [q.verdict, q]));

export const quantityAt = (path) => byPath.get(path);
export const quantityOfVerdict = (name) => byVerdict.get(name);

// C's %g: six significant digits, no trailing zeros, an exponent below
// 1e-4 and from 1e6 on.
function shortest(x) {
  const [m, e] = x.toExponential(5).split("e");
  const exp = Number(e);
  const trim = (s) => (s.includes(".") ? s.replace(/0+$/, "").replace(/\.$/, "") : s);
  if (exp < -4 || exp >= 6) return `${trim(m)}e${exp < 0 ? "-" : "+"}${String(Math.abs(exp)).padStart(2, "0")}`;
  return trim(x.toFixed(5 - exp));
}

// v (in the summary's unit) as quantity_format() prints it: to the row's
// decimals, '+' on a signed quantity, what rounds to zero without a sign,
// "-" for a value that is not a number; with UNIT, the unit as typeset.
// (An exact tie of binary fractions, 0.125 to two decimals, rounds up here
// and to even in C; no measured value is one.)
export function formatQuantity(q, v, flags = 0) {
  if (typeof v !== "number" || Number.isNaN(v)) return "-";
  let plus = q.sign && !(flags & NO_SIGN);
  const tail = flags & UNIT && q.symbol ? ` ${q.symbol}` : "";
  let x = v * q.scale;
  if (Math.abs(x) >= QUANTITY_MAX_FIXED) return shortest(x) + tail;
  if (q.decimals >= 0 && Math.abs(x) < 0.5 * 10 ** -q.decimals) {
    x = 0;
    plus = false;
  }
  const s = q.decimals < 0 ? shortest(x) : x.toFixed(q.decimals);
  return (plus && x > 0 ? "+" : "") + s + tail;
}

// The quantity at path, its label and unit ("RMS (nm)"), and v as printed.
export const labelOf = (q) => (q.symbol ? `${q.label} (${q.symbol})` : q.label);
