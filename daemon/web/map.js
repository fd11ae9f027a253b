// SPDX-License-Identifier: GPL-3.0-or-later
// The live map: the measured points on the aperture, seen from above,
// coloured by the measured z minus the nominal sag at the measured (x, y),
// as the daemon computes it for each point ([x, y, reading, dz]), with a
// colour bar whose ends and middle are labelled in numbers (the map reads
// without colour alone). A point without a deviation (no measurement, or
// off the nominal surface) is drawn grey.

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
  let rmax = 0, dev = 0;
  for (const [x, y, , dz] of points) {
    if (x === null || y === null) continue;
    rmax = Math.max(rmax, Math.hypot(x, y));
    if (dz !== null) dev = Math.max(dev, Math.abs(dz));
  }
  // At least 1 nm at the ends of the bar: a part on its nominal would
  // otherwise show its rounding noise at full colour.
  dev = Math.max(dev, 1e-6);
  const k = (Math.min(w, h) / 2 - 4) / (rmax || 1);
  const size = Math.max(2, Math.min(6, (Math.min(w, h) / Math.sqrt(points.length)) * 0.8));
  for (const [x, y, , dz] of points) {
    if (x === null || y === null) continue;
    ctx.fillStyle = dz === null ? "#8a8f94" : colourScale(dz / dev);
    ctx.fillRect(w / 2 + x * k - size / 2, h / 2 - y * k - size / 2, size, size);
  }
  const unit = (d) => (Math.abs(d) < 1e-3 ? `${(d * 1e6).toPrecision(3)} nm` : `${(d * 1e3).toPrecision(3)} µm`);
  scale.replaceChildren("measured z − nominal sag");
  for (const [t, label] of [[1, `+${unit(dev)}`], [0, "0 (nominal)"], [-1, `−${unit(dev)}`]]) {
    const row = document.createElement("div");
    const swatch = document.createElement("span");
    swatch.className = "swatch";
    swatch.style.background = colourScale(t);
    row.append(swatch, " ", label);
    scale.append(row);
  }
  const foot = document.createElement("div");
  foot.textContent = `${points.length} points, radius ${rmax.toFixed(2)} mm`;
  scale.append(foot);
}
