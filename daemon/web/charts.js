// SPDX-License-Identifier: GPL-3.0-or-later
// The result's charts as SVG, with labelled axes: the Zernike
// coefficients as bars, the radial profile of the residuals.
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
