// SPDX-License-Identifier: GPL-3.0-or-later
// The operator's page in headless Chromium (puppeteer-core, pointed at the
// system's chromium): log in, submit a job, watch the live map fill,
// pause and resume, see the result and its verdict, download the CSV;
// then as a viewer: no mutating controls, and a forged call is refused.
// Run by test-web-browser.py, which starts the daemon; prints one JSON
// line of findings for it to compare, and exits 1 on the first failure.
import { createRequire } from "node:module";
import path from "node:path";

// puppeteer-core as scripts/install-deps installed it (ASPH_NODE_DIR).
const require = createRequire(path.join(process.env.ASPH_NODE_DIR, "package.json"));
const puppeteer = require("puppeteer-core");

const [url, opToken, viewerToken, shots] = process.argv.slice(2);
const chromium = process.env.CHROMIUM || "/usr/bin/chromium";
let n = 0;
const ok = (cond, what) => {
  n++;
  console.log(`${cond ? "ok" : "not ok"} - ${what}`);
  if (!cond) throw new Error(what);
};
const shot = (page, name) => page.screenshot({ path: path.join(shots, `${name}.png`) });
// A part of the page for docs/web (scripts/web-screenshots copies them):
// the box of selector, from the top of the element `from` inside it (or
// its own) to the bottom of `to` (or its own), at most maxHeight pixels.
const docShot = async (page, selector, name, { from, to, maxHeight = 1000 } = {}) => {
  const e = await page.$(selector);
  const clip = await e.evaluate((n, from, to, maxHeight) => {
    const r = n.getBoundingClientRect();
    const top = from ? n.querySelector(from).getBoundingClientRect().top - r.top : 0;
    const bottom = to ? n.querySelector(to).getBoundingClientRect().bottom - r.top : r.height;
    return { x: 0, y: top, width: r.width, height: Math.min(bottom - top, maxHeight) };
  }, from, to, maxHeight);
  await e.screenshot({ path: path.join(shots, `docs-${name}.png`), clip });
};

// Pixels of the live map that differ from its background.
const mapPixels = (page) => page.$eval("#live-map", (c) => {
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let k = 0;
  for (let i = 0; i < d.length; i += 4)
    if (Math.abs(d[i] - 0x20) + Math.abs(d[i + 1] - 0x24) + Math.abs(d[i + 2] - 0x28) > 30) k++;
  return k;
});

// The PSD chart rasterised as the page shows it: the pixels of its line's
// colour (#1d3557; the grid, frame and labels are other colours).
const psdLinePixels = (page) => page.$eval("#psd-chart", async (s) => {
  const url = URL.createObjectURL(new Blob([new XMLSerializer().serializeToString(s)], { type: "image/svg+xml" }));
  const img = new Image();
  await new Promise((resolve, reject) => { img.onload = resolve; img.onerror = reject; img.src = url; });
  const c = document.createElement("canvas");
  [c.width, c.height] = [560, 260];
  const g = c.getContext("2d");
  g.fillStyle = "#fff";
  g.fillRect(0, 0, c.width, c.height);
  g.drawImage(img, 0, 0, c.width, c.height);
  URL.revokeObjectURL(url);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let k = 0;
  for (let i = 0; i < d.length; i += 4)
    if (Math.abs(d[i] - 0x1d) + Math.abs(d[i + 1] - 0x35) + Math.abs(d[i + 2] - 0x57) < 40) k++;
  // the line's width across: it has at least a pixel in most columns
  const xs = [...s.querySelector("path.psd-line").getAttribute("d").matchAll(/[ML]([-0-9.]+),/g)].map((m) => Number(m[1]));
  return [k, Math.max(...xs) - Math.min(...xs)];
});

// The PSD as the chart plots it: each vertex of its line taken back
// through the axes (the decade ticks' positions), and the floor below
// which the chart clips.
const psdPlotted = (page) => page.$eval("#psd-chart", (s) => {
  const axis = (cls, coord, shift) => {
    const t = [...s.querySelectorAll(`text.${cls}`)].map((e) => [Number(e.dataset.log), Number(e.getAttribute(coord)) - shift]);
    const [[k0, p0], [k1, p1]] = [t[0], t[t.length - 1]];
    return { back: (p) => 10 ** (k0 + (p - p0) * (k1 - k0) / (p1 - p0)), lo: Math.min(k0, k1) };
  };
  const x = axis("xtick", "x", 0), y = axis("ytick", "y", 4);
  const pts = [...s.querySelector("path.psd-line").getAttribute("d").matchAll(/[ML]([-0-9.]+),([-0-9.]+)/g)]
    .map((m) => [x.back(Number(m[1])), y.back(Number(m[2]))]);
  const labels = [...s.querySelectorAll("text")].map((e) => e.textContent);
  return { pts, floor: 10 ** y.lo, labels, tabindex: s.getAttribute("tabindex"), aria: s.getAttribute("aria-label") };
});

const stateOf = (page, job) => page.$eval(`#queue tr[data-job="${job}"] .state`, (e) => e.textContent).catch(() => null);

async function login(page, token) {
  await page.goto(url, { waitUntil: "domcontentloaded" });
  await page.waitForSelector("#login-form", { visible: true });
  await page.type("#token", token);
  await page.click("#login-form button[type=submit]");
  await page.waitForSelector("#dashboard", { visible: true });
}

const browser = await puppeteer.launch({
  executablePath: chromium,
  headless: true,
  args: ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"],
});
const findings = {};
try {
  const page = await browser.newPage();
  await page.setViewport({ width: 1280, height: 800 });
  const errors = [];
  page.on("pageerror", (e) => errors.push(String(e)));
  // (a 401 or 404 a fetch answers is the page's business, not an error)
  page.on("console", (m) => m.type() === "error" && !m.text().startsWith("Failed to load resource") &&
    errors.push(m.text()));

  await login(page, opToken);
  const who = await page.$eval("#who", (e) => e.textContent);
  ok(who.includes("operator"), `logged in as operator (${who})`);
  await page.waitForFunction(() => document.querySelector("#instruments tbody").textContent.includes("mock"));
  ok(true, "the mock instrument is listed");
  await shot(page, "1-dashboard");

  // The profiles method asks for its number of profiles, and the estimate
  // follows it: at one h, four profiles hold twice the points of two (the
  // default: one profile sees fewer degrees of freedom than the form's).
  const profilesInput = "#submit-form input[name=profiles]";
  ok(await page.$eval(profilesInput, (e) => e.disabled), "the number of profiles is not asked for a Fermat spiral");
  await page.select("#submit-form select[name=method]", "profiles");
  await page.select("#submit-form select[name=density]", "h");
  await page.$eval("#submit-form input[name=value]", (e) => {
    e.value = "0.05";
    e.dispatchEvent(new Event("input", { bubbles: true }));
  });
  const [enabled, max] = await page.$eval(profilesInput, (e) => [!e.disabled, Number(e.max)]);
  ok(enabled && max === 36, `the profiles method asks for 1 to ${max} profiles`);
  await page.waitForFunction(() => /^Estimated .* for \d+ points$/.test(document.querySelector("#submit-estimate").textContent) &&
    !document.querySelector("#submit-estimate").textContent.endsWith(" 2000 points"), { timeout: 30000 });
  const twoPoints = Number((await page.$eval("#submit-estimate", (e) => e.textContent)).match(/for (\d+) points$/)[1]);
  await page.$eval(profilesInput, (e) => {
    e.value = "4";
    e.dispatchEvent(new Event("input", { bubbles: true }));
  });
  await page.waitForFunction((n) => document.querySelector("#submit-estimate").textContent.endsWith(`for ${n} points`),
    { timeout: 30000 }, 2 * twoPoints);
  ok(true, `four profiles: ${2 * twoPoints} points, two: ${twoPoints}`);

  // Submit: a Fermat spiral of 2000 points, measured for a few seconds.
  await page.select("#submit-form select[name=method]", "fermat");
  await page.select("#submit-form select[name=density]", "points");
  // The estimate follows the form before anything is submitted.
  const estimateFor = async (value) => {
    await page.$eval("#submit-form input[name=value]", (e, v) => {
      e.value = v;
      e.dispatchEvent(new Event("input", { bubbles: true }));
    }, value);
    await page.waitForFunction((v) => document.querySelector("#submit-estimate").textContent.endsWith(`for ${v} points`),
      { timeout: 30000 }, value);
    return page.$eval("#submit-estimate", (e) => [e.textContent, Number(e.dataset.estimate)]);
  };
  const [text500, t500] = await estimateFor("500");
  const [text2000, t2000] = await estimateFor("2000");
  ok(/^Estimated measuring time: \S+/.test(text2000) && t2000 > t500 && t500 > 0,
    `the estimate follows the form (${text500}; ${text2000})`);
  await page.type("#submit-form input[name=part]", "AS-7");
  await page.type("#submit-form input[name=lot]", "L-9");
  await page.type("#submit-form input[name=serial]", "0001");
  await page.type("#submit-form input[name=tolerance]", "3/2(0.5/0.3)");
  await page.waitForFunction(() => document.querySelector("#submit-estimate").textContent.startsWith("Estimated"));
  findings.estimate_s = Number(await page.$eval("#submit-estimate", (e) => e.dataset.estimate));
  await shot(page, "1b-estimate");
  await docShot(page, "section:has(#submit-form)", "submit");
  await page.click("#submit-form button[type=submit]");
  await page.waitForFunction(() => document.querySelector("#submit-form").dataset.lastJob);
  const job = Number(await page.$eval("#submit-form", (e) => e.dataset.lastJob));
  findings.job = job;
  ok(job > 0, `job ${job} submitted`);

  // The live map fills as the points arrive.
  await page.waitForFunction(() => Number(document.querySelector("#live-map").dataset.points || 0) > 100, { timeout: 60000 });
  const pixels = await mapPixels(page);
  ok(pixels > 500, `the live map has ${pixels} non-background pixels`);
  const legend = await page.$eval("#live-scale", (e) => e.textContent);
  ok(legend.includes("nominal sag") && /[+−][0-9.]+ (nm|µm)/.test(legend),
    `the map's colour bar: deviations from the nominal, in numbers (${legend})`);
  await shot(page, "2-live");
  await docShot(page, "section:has(#live-map)", "live");

  // Pause and resume from the queue.
  // (locators retry when a refresh of the queue replaced the row)
  await page.locator(`#queue tr[data-job="${job}"] button[data-action="job.pause"]`).click();
  await page.waitForFunction((j) => document.querySelector(`#queue tr[data-job="${j}"] .state`)?.textContent === "paused", { timeout: 30000 }, job);
  ok((await stateOf(page, job)) === "paused", "paused");
  const pausedAt = Number(await page.$eval("#live-map", (e) => e.dataset.points));
  await shot(page, "3-paused");
  await page.locator(`#queue tr[data-job="${job}"] button[data-action="job.resume"]`).click();

  // The result and its verdict table.
  await page.waitForSelector("#verdict", { visible: true, timeout: 120000 });
  const points = Number(await page.$eval("#live-map", (e) => e.dataset.points));
  ok(points === 2000 && points > pausedAt, `the map holds all 2000 points (${pausedAt} when paused)`);
  const verdict = await page.$eval("#verdict", (e) => e.textContent);
  ok(verdict.includes("RMS (nm)") && verdict.includes("2000 of 2000"), "the result's table");
  const decision = await page.$eval("#result", (e) => [...e.querySelectorAll("h3")].map((h) => h.textContent).find((t) => t.startsWith("Verdict")));
  const items = await page.$$eval("#tolerances tbody tr", (rows) => rows.length);
  ok(/^Verdict: (pass|fail|undecided)$/.test(decision || "") && items >= 1, `the verdict and its table (${decision}, ${items} rows)`);
  // The figures as the page prints them: the caller compares them with the
  // summary through the quantity table.
  findings.figures = await page.evaluate(() => Object.fromEntries(["#verdict", "#pose tbody", "#tolerances tbody"].map((s) =>
    [s.split(" ")[0].slice(1), [...document.querySelectorAll(`${s} tr`)].map((r) => [...r.cells].map((c) => c.textContent))])));
  // The picture loads after the table: wait for it to finish loading. A
  // broken picture completes with no width and fails here.
  await page.waitForFunction(() => document.querySelector("img.residual-map")?.complete, { timeout: 120000 });
  ok(await page.$eval("img.residual-map", (e) => e.complete && e.naturalWidth > 0), "the residual map is drawn");
  await page.waitForFunction(() => document.querySelectorAll("#result svg.chart").length === 3);
  const bars = await page.$$eval("#result svg.chart", (s) => [s[0].querySelectorAll("rect").length, s[1].querySelector("path").getAttribute("d").split("M").length - 1]);
  ok(bars[0] === 36 && bars[1] === 2000, `the Zernike bars (${bars[0]}) and the radial profile (${bars[1]} points)`);
  // The PSD: a log-log chart with labelled axes, its numbers in a table
  // the keyboard opens; the values are compared with psd.csv by the caller.
  const psd = await psdPlotted(page);
  ok(psd.labels.includes("spatial frequency (1/mm)") && psd.labels.includes("PSD (nm² mm)") &&
    psd.pts.length > 10 && psd.tabindex === "0" && /^Power spectral density/.test(psd.aria),
  `the PSD chart: labelled axes, ${psd.pts.length} frequencies, focusable (${psd.aria})`);
  const [linePixels, lineWidth] = await psdLinePixels(page);
  ok(linePixels > 0.8 * lineWidth && lineWidth > 100,
    `the PSD line is drawn (${linePixels} pixels of its colour over ${lineWidth.toFixed(0)} across)`);
  // Tab order: the chart, then its table's disclosure.
  await page.focus("#psd-values summary");
  await page.keyboard.down("Shift");
  await page.keyboard.press("Tab");
  await page.keyboard.up("Shift");
  ok(await page.evaluate(() => document.activeElement.id === "psd-chart"), "Shift+Tab from the table reaches the PSD chart");
  await page.keyboard.press("Tab");
  await page.keyboard.press("Enter");
  ok(await page.$eval("#psd-values", (e) => e.open), "Enter opens the PSD's table of values");
  findings.psd_plotted = psd.pts;
  findings.psd_floor = psd.floor;
  findings.psd_table = await page.$$eval("#psd-values tbody tr", (rows) => rows.map((r) => [...r.cells].map((c) => Number(c.textContent))));
  await page.$eval("#psd-chart", (e) => e.scrollIntoView({ block: "center" }));
  await shot(page, "4b-psd");
  await page.$eval("#psd-values", (e) => { e.open = false; });
  await page.evaluate(() => document.activeElement.blur());
  await docShot(page, "section:has(#result)", "result", { maxHeight: 1000 });
  await docShot(page, "#result", "charts", { from: "#zernike-h", to: "#psd-values", maxHeight: 1400 });
  const links = await page.$$eval("#downloads a", (as) => as.map((a) => a.getAttribute("href")));
  ok(links.some((h) => h.endsWith("psd.csv")), "a download link for the PSD");
  ok(links.some((h) => h.endsWith("residuals.csv")), "a download link for the CSV");
  await page.evaluate(() => document.querySelector("#result").scrollIntoView());
  await shot(page, "4-result");
  findings.csv = await page.evaluate(async (h) => (await fetch(h)).text(), links.find((h) => h.endsWith("residuals.csv")));

  // Keyboard: the login field and buttons are reachable with Tab.
  await page.setViewport({ width: 800, height: 1100, isMobile: true, hasTouch: true });
  await shot(page, "5-tablet");
  await page.screenshot({ path: path.join(shots, "docs-tablet.png") });
  ok(await page.$eval("#dashboard", (e) => e.scrollWidth <= window.innerWidth + 1), "no sideways scrolling on a tablet");

  // A viewer: no mutating controls; a forged call is refused by the server.
  const ctx = await browser.createBrowserContext();
  const vpage = await ctx.newPage();
  await vpage.setViewport({ width: 1280, height: 800 });
  await login(vpage, viewerToken);
  ok((await vpage.$$("button[data-action]")).length === 0, "a viewer sees no job actions");
  ok(await vpage.$eval("#submit-form", (e) => e.offsetParent === null), "a viewer sees no submit form");
  ok(await vpage.$eval("#queue-start", (e) => e.offsetParent === null), "a viewer sees no queue controls");
  const forged = await vpage.evaluate(async (id) => {
    const r = await fetch("/api/rpc", { method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ jsonrpc: "2.0", id: 1, method: "job.requeue", params: { id } }) });
    return r.json();
  }, job);
  ok(forged.error && forged.error.code === 100, `a viewer's forged job.requeue is refused (${JSON.stringify(forged.error)})`);
  await shot(vpage, "6-viewer");
  await vpage.screenshot({ path: path.join(shots, "docs-viewer.png") });
  ok(errors.length === 0, `no errors in the page (${errors.join("; ")})`);
} finally {
  await browser.close();
}
console.log(JSON.stringify(findings));
