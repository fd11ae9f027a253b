#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The web page's cost (docs/web.md), with ratios against baselines of the
same run:
- scan rate: a 20,000 points/s mock scan measured alone, and with one
  headless chromium watching it on the page (events, live map); the rate
  must drop by less than 5 %;
- event backlog: the page's event stream stays open through the scan (it
  is ended only when its unsent events pass limits.max_output_bytes);
- page load: time to the first render of the dashboard with 10,000 jobs in
  the history, against the same with one job.
Exit 77 where chromium or puppeteer-core is not installed."""
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
from daemontest import Client, Daemon, browser_or_skip, web_port  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(HERE, "..", ".."))
POINTS = 60000
chromium, NODE_DIR = browser_or_skip(ROOT)


def scan_rate(c):
    """The measured rate of one job: points over time between the first
    and the last progress event while it measures (no plan, no fit)."""
    c.call("events.subscribe", {"events": ["progress", "job"]})
    job = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": POINTS}})["id"]
    marks = []
    while True:
        msg = c.read_message()
        if msg.get("method") == "job.progress" and msg["params"]["job"] == job:
            p = msg["params"]
            # (the last point once: a repeated 100 % would add time, not points)
            if 0 < p["done"] < p["total"] or \
                    (p["done"] == p["total"] and (not marks or marks[-1][1] != p["total"])):
                marks.append((time.monotonic(), p["done"]))
        if msg.get("method") == "job.state" and msg["params"]["job"] == job and \
                msg["params"]["state"] in ("completed", "failed", "cancelled"):
            break
    c.call("events.unsubscribe")
    (t0, d0), (t1, d1) = marks[0], marks[-1]
    return (d1 - d0) / (t1 - t0)


# time_factor 0.35 of a 20 kHz probe on a fast stage: about 20,000 points/s here.
inst = {"name": "mock", "stage": {"driver": "mock", "options": {"time_factor": 0.35, "speed": 2000}},
        "probe": {"driver": "mock", "options": {"time_factor": 0.35, "rate": 20000}}}
d = Daemon([inst], extra={"http_listen": "127.0.0.1:0", "limits": {"max_queue": 20000}})
failed = False
try:
    d.start()
    url = f"http://127.0.0.1:{web_port(d)}/"
    c = Client(d.socket, timeout=300)
    token = c.call("token.create", {"name": "bench", "role": "operator"})["token"]
    env = dict(os.environ, ASPH_NODE_DIR=NODE_DIR, CHROMIUM=chromium)
    browser = None

    def open_browser():
        return subprocess.Popen(["node", os.path.join(HERE, "bench-web.mjs"), url, token],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)

    def ask(b, line):
        b.stdin.write(line + "\n")
        b.stdin.flush()
        return json.loads(b.stdout.readline())

    alone, watched, opens, mapped = [], [], [], []
    for _ in range(2):
        alone.append(scan_rate(c))
        browser = open_browser()
        ask(browser, "watch 0")
        watched.append(scan_rate(c))
        state = ask(browser, "watch 1.5")
        opens.append(state["opens"])
        mapped.append(state["points"])
        browser.stdin.close()
        browser.wait()
    ra, rw = statistics.mean(alone), statistics.mean(watched)
    drop = 1 - rw / ra
    print(f"scan rate alone:    {ra:9.0f} points/s  ({', '.join(f'{r:.0f}' for r in alone)})")
    print(f"scan rate watched:  {rw:9.0f} points/s  ({', '.join(f'{r:.0f}' for r in watched)})")
    print(f"ratio watched/alone: {rw / ra:.4f} (drop {100 * drop:.2f} %, must be < 5 %)")
    print(f"event stream opens per watched scan: {opens} (1: never ended for backlog); "
          f"points on the live map: {mapped} of {POINTS}")
    failed |= drop >= 0.05 or any(o != 1 for o in opens) or any(m != POINTS for m in mapped)

    # Page load: one job in the history (those above), then 10,000.
    browser = open_browser()
    base = [ask(browser, "load")["ms"] for _ in range(3)]
    c.call("queue.stop")
    n = 10000
    for start in range(0, n, 1000):
        batch = [{"jsonrpc": "2.0", "id": i, "method": "job.submit",
                  "params": {"lens": "weak", "plan": {"method": "fermat", "points": 100},
                             "label": f"bench-{i}", "part": "P", "lot": f"L{i // 100}",
                             "serial": str(i)}} for i in range(start, start + 1000)]
        c.send_raw((json.dumps(batch) + "\n").encode())
        c.read_message()
    queued = [j["id"] for j in c.call("queue.get")["jobs"]]
    for k in range(0, len(queued), 1000):
        c.send_raw((json.dumps([{"jsonrpc": "2.0", "id": j, "method": "job.cancel",
                                 "params": {"id": j}} for j in queued[k:k + 1000]]) + "\n").encode())
        c.read_message()
    full = [ask(browser, "load") for _ in range(3)]
    browser.stdin.close()
    browser.wait()
    tb, tf = statistics.median(base), statistics.median(f["ms"] for f in full)
    print(f"page load, {len(alone) + len(watched)} jobs: {tb:.0f} ms ({base})")
    print(f"page load, {n} more jobs in the history: {tf:.0f} ms ({[f['ms'] for f in full]}), "
          f"ratio {tf / tb:.2f}; history rows drawn: {full[0]['rows']}")
    c.close()
    d.stop()
except Exception:
    print(d.log_text()[-2000:])
    raise
finally:
    d.cleanup()
sys.exit(1 if failed else 0)
