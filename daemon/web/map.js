// SPDX-License-Identifier: GPL-3.0-or-later
// The live map: the measured points on the aperture, seen from above,
// coloured by the probe's reading relative to the mean of those measured,
// with a colour bar whose ends and middle are labelled in numbers (the
// map reads without colour alone).

// A diverging scale: blue (below) to white to red (above), t in [-1, 1].
export function colourScale(t) {
  const s = Math.max(-1, Math.min(1, t));
  const a = Math.round(255 * (1 - Math.abs(s)));
  return s < 0 ? `rgb(${a},${a},255)` : `rgb(255,${a},${a})`;
}

export function drawMap(canvas, points, scale) {
  const ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height;
  ctx.fillStyle = "#202428";
  ctx.fillRect(0, 0, w, h);
  if (!points.length) {
    scale.textContent = "no points yet";
    return;
  }
  let rmax = 0, mean = 0;
  for (const [x, y, v] of points) {
    rmax = Math.max(rmax, Math.hypot(x, y));
    mean += v;
  }
  mean /= points.length;
  let dev = 0;
  for (const p of points) dev = Math.max(dev, Math.abs(p[2] - mean));
  const k = (Math.min(w, h) / 2 - 4) / (rmax || 1);
  const size = Math.max(2, Math.min(6, (Math.min(w, h) / Math.sqrt(points.length)) * 0.8));
  for (const [x, y, v] of points) {
    ctx.fillStyle = colourScale(dev > 0 ? (v - mean) / dev : 0);
    ctx.fillRect(w / 2 + x * k - size / 2, h / 2 - y * k - size / 2, size, size);
  }
  const unit = (d) => (Math.abs(d) < 1e-3 ? `${(d * 1e6).toPrecision(3)} nm` : `${(d * 1e3).toPrecision(3)} µm`);
  scale.replaceChildren();
  for (const [t, label] of [[1, `+${unit(dev)}`], [0, `mean ${mean.toPrecision(6)}`], [-1, `−${unit(dev)}`]]) {
    const row = document.createElement("div");
    const swatch = document.createElement("span");
    swatch.className = "swatch";
    swatch.style.background = colourScale(t);
    row.append(swatch, " ", label);
    scale.append(row);
  }
  scale.append(`${points.length} points, radius ${rmax.toFixed(2)} mm`);
}
