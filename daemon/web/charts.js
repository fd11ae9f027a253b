// SPDX-License-Identifier: GPL-3.0-or-later
// The result's charts as SVG, with labelled axes: the Zernike
// coefficients as bars, the radial profile of the residuals, the PSD.
const NS = "http://www.w3.org/2000/svg";

function svg(tag, attrs = {}, text) {
  const e = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

function frame(title, w, h) {
  const s = svg("svg", { viewBox: `0 0 ${w} ${h}`, role: "img", "aria-label": title, class: "chart" });
  s.append(svg("title", {}, title));
  return s;
}

// Zernike coefficients (nm), Noll/ANSI order as the summary gives them.
export function zernikeBars(coefficients) {
  const w = 560, h = 220, left = 50, bottom = 30, top = 10;
  const s = frame("Zernike coefficients (nm)", w, h);
  const max = Math.max(...coefficients.map(Math.abs), 1e-300);
  const y0 = top + (h - top - bottom) / 2, k = (h - top - bottom) / 2 / max;
  const bw = (w - left - 10) / coefficients.length;
  s.append(svg("line", { x1: left, x2: w - 10, y1: y0, y2: y0, stroke: "#333" }));
  for (const [v, label] of [[max, max.toPrecision(3)], [0, "0"], [-max, (-max).toPrecision(3)]])
    s.append(svg("text", { x: left - 4, y: y0 - v * k + 4, "text-anchor": "end", "font-size": 10 }, label));
  coefficients.forEach((c, i) => {
    const x = left + i * bw;
    s.append(svg("rect", { x: x + 1, width: Math.max(1, bw - 2), y: c > 0 ? y0 - c * k : y0, height: Math.abs(c * k),
      fill: c > 0 ? "#c0392b" : "#2e86c1" }, undefined));
    if (i % 5 === 0) s.append(svg("text", { x: x + bw / 2, y: h - 12, "text-anchor": "middle", "font-size": 10 }, String(i + 1)));
  });
  s.append(svg("text", { x: w / 2, y: h - 1, "text-anchor": "middle", "font-size": 11 }, "term j (nm)"));
  return s;
}

// Residual (nm) against the radius (mm), from residuals.csv.
export function radialProfile(csv) {
  const rows = csv.trim().split("\n").slice(1).map((l) => l.split(",").map(Number));
  const pts = rows.filter((r) => r.length >= 4 && r.every(Number.isFinite)).map(([x, y, , e]) => [Math.hypot(x, y), e]);
  const w = 560, h = 220, left = 60, bottom = 30, top = 10;
  const s = frame("Radial profile of the residuals", w, h);
  if (!pts.length) return s;
  const rmax = Math.max(...pts.map((p) => p[0]), 1e-9);
  const emax = Math.max(...pts.map((p) => Math.abs(p[1])), 1e-300);
  const kx = (w - left - 10) / rmax, ky = (h - top - bottom) / 2 / emax, y0 = top + (h - top - bottom) / 2;
  s.append(svg("line", { x1: left, x2: w - 10, y1: y0, y2: y0, stroke: "#999" }));
  const path = pts.map(([r, e]) => `M${(left + r * kx).toFixed(1)},${(y0 - e * ky).toFixed(1)}h1`).join("");
  s.append(svg("path", { d: path, stroke: "#1d3557", "stroke-width": 2, fill: "none" }));
  for (const [v, label] of [[emax, emax.toPrecision(3)], [0, "0"], [-emax, (-emax).toPrecision(3)]])
    s.append(svg("text", { x: left - 4, y: y0 - v * ky + 4, "text-anchor": "end", "font-size": 10 }, label));
  for (const r of [0, rmax / 2, rmax])
    s.append(svg("text", { x: left + r * kx, y: h - 14, "text-anchor": "middle", "font-size": 10 }, r.toFixed(1)));
  s.append(svg("text", { x: w / 2, y: h - 1, "text-anchor": "middle", "font-size": 11 }, "radius (mm); residual (nm)"));
  return s;
}

// A decade as a label: 0.001 to 1000 plainly, 1e-5 beyond.
const decade = (k) => (k >= -3 && k <= 3 ? String(10 ** k) : `1e${k}`);

// The PSD of the residual from psd.csv (f_per_mm,psd_nm2_mm), log-log:
// the frequencies and the PSD as the daemon computed them (the report's),
// with a decade grid and labelled axes. The values are also in a table
// (psdTable) for a screen reader or a reader who wants numbers.
export function psdChart(rows) {
  const pts = rows.filter(([f, p]) => f > 0 && p > 0);
  const w = 560, h = 260, left = 64, right = 12, top = 10, bottom = 40;
  const s = frame("Power spectral density of the residual, log-log", w, h);
  s.setAttribute("id", "psd-chart");
  s.setAttribute("tabindex", "0");
  if (pts.length < 2) {
    s.append(svg("text", { x: w / 2, y: h / 2, "text-anchor": "middle" }, "too few points for a spectrum"));
    return s;
  }
  const lf = pts.map(([f]) => Math.log10(f)), lp = pts.map(([, p]) => Math.log10(p));
  const x0 = Math.floor(Math.min(...lf)), x1 = Math.max(Math.ceil(Math.max(...lf)), x0 + 1);
  const y1 = Math.ceil(Math.max(...lp)), y0 = Math.max(Math.min(Math.floor(Math.min(...lp)), y1 - 1), y1 - 12);
  const u = (l) => left + (l - x0) / (x1 - x0) * (w - left - right);
  const v = (l) => top + (y1 - Math.max(l, y0)) / (y1 - y0) * (h - top - bottom);
  s.setAttribute("aria-label", `Power spectral density of the residual, log-log: ${pts.length} spatial frequencies ` +
    `from ${pts[0][0].toPrecision(3)} to ${pts[pts.length - 1][0].toPrecision(3)} per mm, ` +
    `PSD from ${Math.min(...pts.map((p) => p[1])).toPrecision(3)} to ${Math.max(...pts.map((p) => p[1])).toPrecision(3)} nm² mm`);
  for (let k = x0; k <= x1; k++) {
    s.append(svg("line", { x1: u(k), x2: u(k), y1: top, y2: h - bottom, stroke: "#d5d8dc" }));
    s.append(svg("text", { x: u(k), y: h - bottom + 14, "text-anchor": "middle", "font-size": 10, class: "xtick", "data-log": k }, decade(k)));
  }
  const step = Math.ceil((y1 - y0) / 6);
  for (let k = y1; k >= y0; k -= step) {
    s.append(svg("line", { x1: left, x2: w - right, y1: v(k), y2: v(k), stroke: "#d5d8dc" }));
    s.append(svg("text", { x: left - 4, y: v(k) + 4, "text-anchor": "end", "font-size": 10, class: "ytick", "data-log": k }, decade(k)));
  }
  s.append(svg("rect", { x: left, y: top, width: w - left - right, height: h - top - bottom, fill: "none", stroke: "#333" }));
  const d = pts.map(([f, p], i) => `${i ? "L" : "M"}${u(Math.log10(f)).toFixed(2)},${v(Math.log10(p)).toFixed(2)}`).join("");
  s.append(svg("path", { d, stroke: "#1d3557", "stroke-width": 1.5, fill: "none", class: "psd-line" }));
  s.append(svg("text", { x: (left + w - right) / 2, y: h - 6, "text-anchor": "middle", "font-size": 11 }, "spatial frequency (1/mm)"));
  s.append(svg("text", { x: 12, y: (top + h - bottom) / 2, "text-anchor": "middle", "font-size": 11,
    transform: `rotate(-90 12 ${(top + h - bottom) / 2})` }, "PSD (nm² mm)"));
  return s;
}

// The PSD's numbers as a table, in a disclosure the keyboard opens.
export function psdTable(rows, el) {
  const fmt = (x) => x.toPrecision(4);
  return el("details", { id: "psd-values" }, el("summary", {}, `PSD values (${rows.length} frequencies)`),
    el("table", {}, el("thead", {}, el("tr", {}, el("th", {}, "f (1/mm)"), el("th", {}, "PSD (nm² mm)"))),
      el("tbody", {}, ...rows.map(([f, p]) => el("tr", {}, el("td", {}, fmt(f)), el("td", {}, fmt(p)))))));
}

// psd.csv's rows as numbers: [[f, psd], ...].
export function parsePsd(csv) {
  return csv.trim().split("\n").slice(1).map((l) => l.split(",").map(Number))
    .filter((r) => r.length === 2 && r.every(Number.isFinite));
}
