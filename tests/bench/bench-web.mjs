// SPDX-License-Identifier: GPL-3.0-or-later
// The browser side of bench-web.py: logs in to the page and, per line
// read on stdin, answers one line of JSON on stdout:
//   "watch SECONDS"  keep the dashboard open that long (live map, events),
//                    then report the map's points and the stream's opens
//   "load"           reload the page and time its first render (the
//                    dashboard with its queue and history drawn)
import { createRequire } from "node:module";
import path from "node:path";
import readline from "node:readline";

const require = createRequire(path.join(process.env.ASPH_NODE_DIR, "package.json"));
const puppeteer = require("puppeteer-core");
const [url, token] = process.argv.slice(2);

const browser = await puppeteer.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"],
});
const page = await browser.newPage();
await page.setViewport({ width: 1280, height: 800 });
// Counts the event streams the page opens (1 unless one was ended).
await page.evaluateOnNewDocument(() => {
  window.streamOpens = 0;
  const ES = window.EventSource;
  window.EventSource = class extends ES {
    constructor(...a) {
      super(...a);
      this.addEventListener("open", () => window.streamOpens++);
    }
  };
});
await page.goto(url, { waitUntil: "domcontentloaded" });
await page.waitForSelector("#login-form", { visible: true });
await page.type("#token", token);
await page.click("#login-form button[type=submit]");
await page.waitForSelector("#dashboard", { visible: true });

const rendered = () => page.waitForFunction(() =>
  document.querySelector("#instruments tbody").rows.length > 0 &&
  document.querySelector("#history tbody").rows.length > 0, { timeout: 120000 });

for await (const line of readline.createInterface({ input: process.stdin })) {
  const [cmd, arg] = line.split(" ");
  if (cmd === "watch") {
    await new Promise((r) => setTimeout(r, Number(arg) * 1000));
    const state = await page.evaluate(() => ({ points: Number(document.querySelector("#live-map").dataset.points || 0), opens: window.streamOpens }));
    console.log(JSON.stringify(state));
  } else if (cmd === "load") {
    const t0 = Date.now();
    await page.reload({ waitUntil: "domcontentloaded" });
    await rendered();
    const rows = await page.$eval("#history tbody", (t) => t.rows.length);
    console.log(JSON.stringify({ ms: Date.now() - t0, rows }));
  } else break;
}
await browser.close();
