// SPDX-License-Identifier: GPL-3.0-or-later
// The operator's page: the daemon's JSON-RPC methods over POST /api/rpc,
// its notifications over Server-Sent Events (/api/events), the measured
// points for the live map in batches (/api/jobs/ID/points), result files
// from /api/jobs/ID/files/NAME. The server checks every call; the role
// only decides what the page offers.
import { drawMap, colourScale } from "./map.js";
import { zernikeBars, radialProfile, psdChart, psdTable, parsePsd } from "./charts.js";
import { csvText } from "./csv.js";
import { PLAN_MAX_PROFILES, planMethods, presets } from "./names.js";
import { NO_SIGN, UNIT, formatQuantity, labelOf, quantityAt, quantityOfVerdict } from "./quantity.js";

const $ = (id) => document.getElementById(id);
let role = null;
let rpcId = 0;
let events = null;
let live = { job: 0, points: [], next: 0, timer: 0 };
let history = { offset: 0, limit: 25, filter: {} };

async function rpc(method, params = {}) {
  const r = await fetch("/api/rpc", {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ jsonrpc: "2.0", id: ++rpcId, method, params }),
  });
  if (r.status === 401) {
    showLogin();
    throw new Error("not logged in");
  }
  const answer = await r.json();
  if (answer.error) {
    const detail = answer.error.data && answer.error.data.detail;
    throw new Error(answer.error.message + (detail ? ": " + detail : ""));
  }
  return answer.result;
}

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c instanceof Node ? c : String(c ?? ""));
  return e;
}

function pls(j) {
  return [j.part, j.lot, j.serial].map((x) => x ?? "–").join(" / ");
}

// ------------------------------------------------------------- login

function showLogin() {
  $("login-view").hidden = false;
  $("dashboard").hidden = true;
  $("logout").hidden = true;
  $("who").textContent = "";
  if (events) events.close();
  events = null;
}

async function start() {
  let hello;
  try {
    hello = await rpc("hello");
  } catch {
    return;
  }
  role = hello.peer.role;
  document.body.dataset.role = role;
  $("who").textContent = `${hello.peer.name}, ${role}`;
  $("login-view").hidden = true;
  $("dashboard").hidden = false;
  $("logout").hidden = false;
  await rpc("events.subscribe", { events: ["job", "progress", "instrument", "queue"] });
  events = new EventSource("/api/events");
  events.onmessage = (m) => onEvent(JSON.parse(m.data));
  // A stream that ended (its buffer overflowed, or the daemon restarted):
  // the browser reconnects; the state is read afresh.
  events.onopen = () => scheduleRefresh();
  await refresh();
  if (role !== "viewer") scheduleEstimate();
}

$("login-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  $("login-error").textContent = "";
  const r = await fetch("/api/login", {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ token: $("token").value }),
  });
  const body = await r.json().catch(() => ({}));
  if (!r.ok) {
    $("login-error").textContent = body.error || `login refused (${r.status})`;
    return;
  }
  $("token").value = "";
  await start();
});

$("logout").addEventListener("click", async () => {
  await fetch("/api/logout", { method: "POST", headers: { "Content-Type": "application/json" }, body: "{}" });
  showLogin();
});

// ------------------------------------------------------------ events

function onEvent(msg) {
  const p = msg.params;
  if (msg.method === "job.progress") {
    if (p.job === live.job || !live.job) showProgress(p);
    return;
  }
  if (msg.method === "job.state" && p.job === live.job &&
      ["completed", "failed", "cancelled"].includes(p.state)) {
    clearInterval(live.timer);
    const job = live.job;
    fetchPoints().then(() => (p.state === "completed" ? showResult(job) : null));
    $("live-text").textContent = `Job ${job} ${p.state}${p.reason ? ": " + p.reason : ""}.`;
  }
  scheduleRefresh();
}

// Events come in bursts (a batch of submissions, a queue cancelled): the
// state is read again at most four times a second, not once per event.
let refreshTimer = 0;
function scheduleRefresh() {
  if (refreshTimer) return;
  refreshTimer = setTimeout(() => {
    refreshTimer = 0;
    refresh().catch(() => {});
  }, 250);
}

async function refresh() {
  const [inst, queue] = await Promise.all([rpc("instrument.list"), rpc("queue.get")]);
  renderInstruments(inst.instruments);
  renderQueue(queue);
  await loadHistory();
  const running = inst.instruments.find((i) => i.job && i.state !== "idle");
  if (running && running.job !== live.job) startLive(running.job, running.progress);
}

// ------------------------------------------------------- instruments

function renderInstruments(list) {
  const tbody = $("instruments").tBodies[0];
  tbody.replaceChildren();
  const sel = document.querySelector("#submit-form select[name=instrument]");
  const chosen = sel.value;
  sel.replaceChildren(el("option", { value: "" }, "any"));
  for (const i of list) {
    const lock = i.lock ? `locked by ${i.lock.holder}${i.lock.reason ? ": " + i.lock.reason : ""}` : "free";
    tbody.append(el("tr", {}, el("td", {}, i.name), el("td", { class: "state" }, i.state),
      el("td", {}, i.job ?? "–"), el("td", {}, lock), el("td", { class: i.fault ? "error" : "" }, i.fault ?? "none")));
    sel.append(el("option", { value: i.name }, i.name));
  }
  sel.value = chosen;
}

// -------------------------------------------------------------- queue

async function act(method, params) {
  $("action-error").textContent = "";
  try {
    await rpc(method, params);
  } catch (e) {
    $("action-error").textContent = `${method}: ${e.message}`;
  }
  await refresh();
}

function actions(j) {
  const td = el("td", { class: "operator" });
  if (role === "viewer") return td;   // the server refuses them anyway
  const b = (label, method, params) =>
    td.append(el("button", { type: "button", "data-action": method, onclick: () => act(method, params) }, label));
  if (j.state === "running") b("Pause", "job.pause", { id: j.id });
  if (j.state === "paused" || j.state === "interrupted") b("Resume", "job.resume", { id: j.id });
  if (["queued", "running", "paused", "interrupted"].includes(j.state)) b("Cancel", "job.cancel", { id: j.id });
  if (["failed", "cancelled", "interrupted"].includes(j.state)) b("Requeue", "job.requeue", { id: j.id });
  return td;
}

let dragged = null;

function renderQueue(q) {
  $("queue-state").textContent = q.running ? "(running)" : "(stopped)";
  const tbody = $("queue").tBodies[0];
  tbody.replaceChildren();
  q.jobs.forEach((j, position) => {
    const p = j.progress;
    const tr = el("tr", { "data-job": j.id },
      el("td", {}, j.id), el("td", { class: "state" }, j.state), el("td", {}, typeof j.lens === "string" ? j.lens : "prescription"),
      el("td", {}, planText(j.plan, j.measured)), el("td", {}, pls(j)), el("td", {}, j.priority),
      el("td", {}, `${p.done} / ${p.total}`), actions(j));
    if (role !== "viewer" && j.state === "queued") {
      // Reorder by drag, or with the keyboard: Alt+Up / Alt+Down.
      tr.draggable = true;
      tr.tabIndex = 0;
      tr.addEventListener("dragstart", () => (dragged = j.id));
      tr.addEventListener("dragover", (e) => e.preventDefault());
      tr.addEventListener("drop", (e) => {
        e.preventDefault();
        if (dragged && dragged !== j.id) act("queue.move", { id: dragged, position });
      });
      tr.addEventListener("keydown", (e) => {
        if (e.altKey && (e.key === "ArrowUp" || e.key === "ArrowDown"))
          act("queue.move", { id: j.id, position: Math.max(0, position + (e.key === "ArrowUp" ? -1 : 1)) });
      });
    }
    tbody.append(tr);
  });
}

$("queue-start").addEventListener("click", () => act("queue.start", {}));
$("queue-stop").addEventListener("click", () => act("queue.stop", {}));

// ------------------------------------------------------------- submit

// The presets and plan methods from libasph's tables (names.js): strong on
// the Fermat spiral unless the operator picks another.
function fillChoices(form) {
  const option = (value, text, chosen) => el("option", { value, ...(chosen ? { selected: "" } : {}) }, text);
  form.elements.lens.replaceChildren(...presets.map((p) => option(p, p, p === "strong")));
  form.elements.method.replaceChildren(...planMethods.map((m) => option(m.name, m.title, m.name === "fermat")));
  form.elements.profiles.max = PLAN_MAX_PROFILES;
}
fillChoices($("submit-form"));

// A job's plan as the queue shows it; a job of measured data has none.
function planText(plan, measured) {
  if (!plan) return measured ? `measured ${measured.format} data` : "";
  return plan.for_tolerance ? `for the tolerance (U ≤ ${plan.capability} T${plan.method ? `, ${plan.method}` : ""})`
    : `${plan.method} ${plan.density} ${plan.value}`;
}

// The plan for the tolerance (docs/sampling-plans.md): the daemon chooses
// the method and density when the job runs, so those fields rest.
function formPlan(f) {
  if (f.get("for_tolerance") !== "on") {
    const plan = { method: f.get("method"), [f.get("density")]: Number(f.get("value")) };
    if (f.get("method") === "profiles") plan.profiles = Number(f.get("profiles"));
    return plan;
  }
  const plan = { for_tolerance: true };
  if (f.get("capability")) plan.capability = Number(f.get("capability"));
  return plan;
}

// The number of profiles is the profiles method's own: asked for it only;
// the plan for the tolerance asks for none of the plan's fields.
function followMethod(form) {
  const tol = form.elements.for_tolerance.checked;
  for (const k of ["method", "density", "value"]) form.elements[k].disabled = tol;
  form.elements.capability.disabled = !tol;
  form.elements.profiles.disabled = tol || form.elements.method.value !== "profiles";
}
for (const k of ["method", "for_tolerance"])
  $("submit-form").elements[k].addEventListener("change", (e) => followMethod(e.target.form));
followMethod($("submit-form"));

// The form as job.submit's parameters; throws an Error saying which field
// does not read.
async function submitParams(form) {
  const f = new FormData(form);
  const params = { lens: f.get("lens"), plan: formPlan(f) };
  const file = f.get("prescription");
  if (file && file.size) {
    try {
      params.lens = JSON.parse(await file.text());
    } catch (err) {
      throw new Error(`${file.name}: not JSON: ${err.message}`);
    }
  }
  params.fit = { dof: f.get("dof"), residual: f.get("residual"), robust: f.get("robust") === "on" };
  if (f.get("zernike")) params.fit.zernike = Number(f.get("zernike"));
  const tol = f.get("tolerance").trim();
  if (tol) {
    // a call-out as text, or the whole tolerance as JSON (docs/characterization.md)
    try {
      params.tolerance = tol.startsWith("{") ? JSON.parse(tol) : tol;
    } catch (err) {
      throw new Error(`tolerance: not JSON: ${err.message}`);
    }
  }
  for (const k of ["label", "part", "lot", "serial", "instrument"]) if (f.get(k)) params[k] = f.get(k);
  if (f.get("priority")) params.priority = Number(f.get("priority"));
  return params;
}

function duration(s) {
  const t = Math.round(s);
  if (t < 60) return `${t} s`;
  if (t < 3600) return `${Math.floor(t / 60)} min ${t % 60} s`;
  const m = Math.round(s / 60);
  return `${Math.floor(m / 60)} h ${m % 60} min`;
}

// The measuring time before submitting (job.estimate queues nothing): asked
// again 400 ms after the form last changed, and an answer that a later
// change has overtaken is dropped.
let estimateTimer = 0;
let estimateSeq = 0;
async function showEstimate() {
  const seq = ++estimateSeq;
  const out = $("submit-estimate");
  let text;
  if ($("submit-form").elements.for_tolerance.checked) {
    // the search characterizes many plans: it runs when the job does, not
    // on every change of the form
    out.textContent = "The plan is chosen for the tolerance when the job runs (the job's result says which and why)";
    out.dataset.estimate = "";
    out.classList.remove("error");
    return;
  }
  try {
    const e = await rpc("job.estimate", await submitParams($("submit-form")));
    text = e.estimate_s === null
      ? `${e.points} points; the instrument gives no time estimate without its device`
      : `Estimated measuring time: ${duration(e.estimate_s)} for ${e.points} points`;
    out.dataset.estimate = e.estimate_s ?? "";
    out.classList.remove("error");
  } catch (err) {
    text = `No estimate: ${err.message}`;
    out.dataset.estimate = "";
    out.classList.add("error");
  }
  if (seq === estimateSeq) out.textContent = text;
}

function scheduleEstimate() {
  clearTimeout(estimateTimer);
  estimateTimer = setTimeout(() => showEstimate().catch(() => {}), 400);
}

$("submit-form").addEventListener("input", scheduleEstimate);
$("submit-form").addEventListener("change", scheduleEstimate);

$("submit-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  $("submit-error").textContent = "";
  try {
    const job = await rpc("job.submit", await submitParams(e.target));
    e.target.dataset.lastJob = job.id;
  } catch (err) {
    $("submit-error").textContent = err.message;
  }
  await refresh();
});

// --------------------------------------------------------------- live

function showProgress(p) {
  if (p.job !== live.job) startLive(p.job, p);
  // In phase "uncertainty" the bar counts the Monte Carlo's trials.
  const t = p.trials;
  $("live-progress").max = Math.max(1, t ? t.planned : p.total);
  $("live-progress").value = t ? t.done : p.done;
  const eta = p.eta_s >= 0 ? `, about ${p.eta_s.toFixed(0)} s left` : "";
  $("live-text").textContent = t
    ? `Uncertainty: ${t.done} of ${t.planned} trials, ${t.rate.toFixed(1)} trials/s${eta}`
    : p.phase === "characterizing" ? `Characterizing ${p.done} points`
    : p.phase === "planning" ? `Choosing the plan for the tolerance: ${p.done} of at most ${p.total} characterizations`
    : `${p.done} of ${p.total} points, ${p.rate.toFixed(0)} points/s${eta}`;
}

function startLive(job, progress) {
  clearInterval(live.timer);
  live = { job, points: [], next: 0, timer: 0 };
  $("live-job").textContent = `#${job}`;
  if (progress) showProgress({ ...progress, job });
  live.timer = setInterval(fetchPoints, 500);
  drawMap($("live-map"), [], $("live-scale"));
}

// The points arrive in batches: one request every half second takes all
// those measured since the last (never one event per point). Requests of
// one job run one after the other; at most one waits behind the running one.
function fetchPoints() {
  const l = live;
  if (!l.job) return Promise.resolve();
  if (l.waiting) return l.chain;
  l.waiting = true;
  l.chain = (l.chain || Promise.resolve()).then(() => {
    l.waiting = false;
    return fetchBatches(l);
  });
  return l.chain;
}

async function fetchBatches(l) {
  for (;;) {
    const r = await fetch(`/api/jobs/${l.job}/points?from=${l.next}`);
    if (!r.ok) break;
    const batch = await r.json();
    l.points.push(...batch.points);
    l.next += batch.points.length;
    if (batch.points.length < 20000) break;
  }
  if (l !== live) return;
  drawMap($("live-map"), l.points, $("live-scale"));
  $("live-map").dataset.points = l.points.length;
}

// ------------------------------------------------------------- result

// A summary's quantity: its label and unit, and its value as printed.
const quantityRow = (s, path) => {
  const q = quantityAt(path);
  return [labelOf(q), formatQuantity(q, s[path])];
};

async function showResult(id) {
  const r = await rpc("job.result", { id });
  const s = r.summary;
  $("result-job").textContent = `#${id}`;
  const rows = [["lens", s.lens], ["points used", `${s.n_used} of ${s.n_points}`],
    ...["rms_nm", "pv_nm", "pvr_nm", "slope_rms_urad"].map((p) => quantityRow(s, p)),
    ["converged", s.converged ? "yes" : "no"]];
  const table = el("table", { id: "verdict" }, el("tbody", {}, ...rows.map(([k, v]) => el("tr", {}, el("th", {}, k), el("td", {}, v)))));
  const dofRow = ([k, v]) => {
    const q = quantityAt(`dof.${k}`);
    return el("tr", {}, el("td", {}, k), el("td", {}, formatQuantity(q, v, UNIT)),
      el("td", {}, formatQuantity(q, (s.uncertainty || {})[k], UNIT | NO_SIGN)));
  };
  const pose = el("table", { id: "pose" }, el("thead", {}, el("tr", {}, el("th", {}, "DOF"), el("th", {}, "value"), el("th", {}, "± u"))),
    el("tbody", {}, ...Object.entries(s.dof || {}).map(dofRow)));
  const files = el("ul", { id: "downloads" }, ...Object.values(r.files).map((name) =>
    el("li", {}, el("a", { href: `/api/jobs/${id}/files/${encodeURIComponent(name)}`, download: `job${id}-${name}` }, name))));
  const parts = [table];
  if (s.verdict) {
    // ISO 14253-1: each toleranced quantity with its value, U and limit
    // a zone two-sided about zero has its limit as ±L, as in the report
    const item = (i) => {
      const q = quantityOfVerdict(i.quantity);
      return el("tr", {}, el("td", {}, labelOf(q)), el("td", {}, formatQuantity(q, i.value)),
        el("td", {}, formatQuantity(q, i.U, NO_SIGN)),
        el("td", {}, (q.two_sided ? "±" : "") + formatQuantity(q, i.limit, NO_SIGN)), el("td", {}, i.verdict));
    };
    parts.push(el("h3", {}, `Verdict: ${s.verdict.overall}`), el("table", { id: "tolerances" },
      el("thead", {}, el("tr", {}, ...["quantity", "value", "U", "limit", "verdict"].map((h) => el("th", {}, h)))),
      el("tbody", {}, ...s.verdict.items.map(item))));
  } else parts.push(el("p", {}, "No tolerance was given: no verdict."));
  const ch = r.plan_for_tolerance;
  if (ch) {
    // why this plan: each toleranced quantity's U against its tolerance
    parts.push(el("h3", {}, "Plan for the tolerance"),
      el("p", { id: "plan-choice" }, `${ch.plan.method}, ${ch.plan.points} points (h = ${ch.plan.h.toPrecision(4)}), ` +
        `${duration(ch.estimate_s)} predicted: the shortest whose U ≤ ${ch.capability} T for every quantity`),
      el("table", { id: "plan-quantities" },
        el("thead", {}, el("tr", {}, ...["quantity", "T", "U (k = 2)", "U/T"].map((h) => el("th", {}, h)))),
        el("tbody", {}, ...ch.quantities.map((q) => el("tr", {}, el("td", {}, q.quantity),
          el("td", {}, q.limit.toPrecision(4)), el("td", {}, q.U.toPrecision(4)), el("td", {}, q.ratio.toFixed(3)))))));
  }
  parts.push(el("h3", {}, "Pose"), pose);
  if (s.zernike_nm) parts.push(el("h3", { id: "zernike-h" }, "Zernike coefficients"), zernikeBars(s.zernike_nm));
  if (r.files.residuals) {
    const csv = await (await fetch(`/api/jobs/${id}/files/${r.files.residuals}`)).text();
    parts.push(el("h3", {}, "Radial profile"), radialProfile(csv));
  }
  if (r.files.psd) {
    const rows = parsePsd(await (await fetch(`/api/jobs/${id}/files/${r.files.psd}`)).text());
    parts.push(el("h3", {}, "Power spectral density"), psdChart(rows), psdTable(rows, el));
  }
  parts.push(el("h3", {}, "Downloads"), files);
  if (r.files.map) parts.splice(1, 0, el("img", { src: `/api/jobs/${id}/files/${r.files.map}`, alt: `residual map of job ${id}`, class: "residual-map" }));
  if (r.provenance) parts.push(el("h3", {}, "Provenance"), el("pre", {}, JSON.stringify(r.provenance, null, 1)));
  $("result").replaceChildren(...parts);
}

// ------------------------------------------------------------ history

async function loadHistory() {
  const params = { offset: history.offset, limit: history.limit, ...history.filter };
  const list = await rpc("job.list", params);
  const tbody = $("history").tBodies[0];
  tbody.replaceChildren();
  for (const j of list.jobs) {
    const show = j.state === "completed" ? el("button", { type: "button", onclick: () => showResult(j.id) }, "Result") : "";
    tbody.append(el("tr", { "data-job": j.id }, el("td", {}, j.id), el("td", { class: "state" }, j.state),
      el("td", {}, j.instrument), el("td", {}, j.label ?? ""), el("td", {}, pls(j)), el("td", {}, j.finished ?? ""), el("td", {}, show)));
  }
  $("history-prev").disabled = history.offset === 0;
  $("history-next").disabled = list.jobs.length < history.limit;
}

$("history-form").addEventListener("submit", (e) => {
  e.preventDefault();
  const f = new FormData(e.target);
  history.filter = {};
  for (const k of ["instrument", "label", "part", "lot", "serial"]) if (f.get(k)) history.filter[k] = f.get(k);
  if (f.get("state")) history.filter.states = [f.get("state")];
  history.offset = 0;
  loadHistory();
});
// The filtered history as CSV (up to 1000 jobs, newest first).
$("history-csv").addEventListener("click", async () => {
  const list = await rpc("job.list", { limit: 1000, ...history.filter });
  const cols = ["id", "state", "instrument", "label", "part", "lot", "serial", "submitted", "started", "finished", "reason"];
  const text = csvText(cols, list.jobs);
  const a = el("a", { href: URL.createObjectURL(new Blob([text], { type: "text/csv" })), download: "asphd-history.csv" });
  document.body.append(a);
  a.click();
  a.remove();
});
$("history-prev").addEventListener("click", () => { history.offset = Math.max(0, history.offset - history.limit); loadHistory(); });
$("history-next").addEventListener("click", () => { history.offset += history.limit; loadHistory(); });

export { colourScale };
start().catch(() => showLogin());
