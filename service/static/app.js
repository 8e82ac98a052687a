// MXS planner observation-preparation page: an ordinary client of the public API.
// POST v1/target-lists reads the table (the CLI's reader), POST v1/jobs runs the plan, and
// the result is drawn here from the response and GET v1/instrument (arms to scale). The form
// (controls, defaults, the request) is form.js's.
"use strict";

const $ = (id) => document.getElementById(id);
const FIELD_LABELS = { position_angle_deg: "position angle", method: "allocation method",
  solver: "solver", segmentation_mode: "segmentation", time_limit_s: "time limit",
  targets: "targets", threshold_mm: "segmentation threshold", park_move_limit_s: "longest move from park", seed: "seed",
  exposure_time_s: "exposure time", acquisition_s: "acquisition per pointing", max_exposures: "most exposures",
  min_priority_per_exposure: "least priority per exposure", min_targets_per_exposure: "fewest targets per exposure",
  obs_date: "observation date", position_angle_range_deg: "position angle range",
  position_angle_step_deg: "position angle step", sky_positions: "sky positions",
  sky_radius_arcsec: "least distance of sky from a target", locked: "locks", excluded_targets: "exclusions",
  keep_configurations: "kept configurations" };
// Controls that change no plan by themselves (the lock form adds a lock only on its buttons).
const NOT_PLAN_INPUTS = new Set(["token", "lock-target", "lock-arm", "keep-k"]);
// The plan shown: `origin` says which input it was made from and when (null: none shown).
const state = { instrument: null, list: null, result: null, request: null, running: false, jobId: null,
  origin: null, defaults: null, touched: new Set(), resultText: null };

// ------------------------------------------------------------------------ HTTP helpers

function authHeaders() {
  const token = $("token").value.trim();
  return token ? { Authorization: "Bearer " + token } : {};
}

// An answer's status, its JSON body (null if none) and its text as sent.
async function fetchJson(url, options) {
  const r = await fetch(url, options);
  const text = await r.text();
  let body = null;
  try { body = JSON.parse(text); } catch (e) { body = null; }
  return { status: r.status, body, text };
}

function errorText(status, body) {
  if (body && typeof body.message === "string") return body.message;
  if (body && typeof body.detail === "string") return body.detail;
  return "HTTP " + status;
}

// A 422 `loc` such as ["body", "plan", "request", "targets", 3, "dec_deg"] names the file's
// row, line and column when the targets came from an uploaded table.
function describeLoc(loc, list) {
  const parts = (loc || []).filter((p) => p !== "body");
  const k = parts.indexOf("targets");
  if (k >= 0 && typeof parts[k + 1] === "number" && list && list.targets[parts[k + 1]]) {
    const t = list.targets[parts[k + 1]];
    const field = parts[k + 2];
    const column = field && list.columns[field] ? list.columns[field] : field;
    const line = t.line ? `, line ${t.line}` : "";
    return `${list.filename}: row ${t.row}${line}` + (column ? `, column '${column}'` : "") +
      ` (target ${t.id})`;
  }
  const lock = lockLoc(parts);
  if (lock) return lock;
  const last = parts.filter((p) => typeof p === "string").pop();
  return FIELD_LABELS[last] || parts.join(".") || "request";
}

// A loc in the locks, exclusions or sky positions: "lock of b to arm 3 (locked[0])".
function lockLoc(parts) {
  const field = ["locked", "excluded_targets", "sky_positions"].find((f) => parts.includes(f));
  if (!field) return null;
  const i = parts[parts.indexOf(field) + 1];
  if (typeof i !== "number") return FIELD_LABELS[field];
  let sent = [];
  try { sent = extraFields()[field] || []; } catch (e) { sent = []; }
  const name = `${field}[${i}]`;
  if (field === "locked" && sent[i]) return `lock of ${sent[i].target_id} to arm ${sent[i].arm} (${name})`;
  if (field === "excluded_targets" && sent[i] !== undefined) return `exclusion of ${sent[i]} (${name})`;
  return `${FIELD_LABELS[field]} ${i + 1} (${name})`;
}

function validationMessages(body, list) {
  if (!body || !Array.isArray(body.detail)) return null;
  return body.detail.map((e) => `${describeLoc(e.loc, list)}: ${e.msg}`);
}

function showError(lines) {
  const box = $("error");
  box.textContent = Array.isArray(lines) ? lines.join("\n") : String(lines);
  box.hidden = false;
}

function clearError() { $("error").hidden = true; $("error").textContent = ""; }

// ------------------------------------------------------------------------ targets

async function readTargetList() {
  const form = new FormData();
  const file = $("file").files[0];
  if (file) form.append("file", file, file.name);
  else form.append("file", new Blob([$("targets").value], { type: "text/csv" }), "pasted.csv");
  const r = await fetchJson("v1/target-lists", { method: "POST", headers: authHeaders(), body: form });
  if (r.status !== 200) {
    const msgs = validationMessages(r.body, null);
    throw new Error(msgs ? msgs.map((m) => m.replace(/^file: /, "")).join("\n") : errorText(r.status, r.body));
  }
  showTableInfo(r.body);
  offerTargetIds(r.body.targets);
  return r.body;
}

// Read the chosen file at once, so its notices and errors show before planning; an error for
// the new input also clears the plan of the old one.
async function previewTable() {
  showInputUsed();
  markStale();
  if (!$("file").files[0] || state.running) return;
  clearError();
  try { await readTargetList(); } catch (e) { $("table-info").hidden = true; clearResult(); showError(e.message); }
}

// Which input the plan uses: the chosen file, else the pasted table (greyed while a file is chosen).
function showInputUsed() {
  const file = $("file").files[0];
  $("targets").classList.toggle("unused", Boolean(file));
  $("clear-file").hidden = !file;
  $("input-used").textContent = file ? `not used: the plan reads the file ${file.name} (type here to use this table instead)` :
    "the pasted table is used";
}

// Typing in the table switches the input back to it.
function usePastedTable() {
  if ($("file").files[0]) { $("file").value = ""; $("table-info").hidden = true; }
  showInputUsed();
  markStale();
}

function showTableInfo(list) {
  const box = $("table-info");
  box.replaceChildren();
  const cols = Object.entries(list.columns).map(([k, v]) => `${k} <- ${v === null ? "(none)" : v}`);
  box.append(el("p", {}, `${plural(list.targets.length, "target")} read from ${list.filename} (${cols.join(", ")}).`));
  if (list.notices.length) box.append(el("ul", {}, ...list.notices.map((n) => el("li", {}, n))));
  box.hidden = false;
}

// ------------------------------------------------------------------------ the job

async function runPlan() {
  if (state.running) return;
  state.running = true;
  $("go").disabled = true;
  clearError();
  clearResult();
  try {
    setStatus("reading the target table ...", 0);
    const list = await readTargetList();
    const request = planRequest(list);
    const r = await fetchJson("v1/jobs", { method: "POST",
      headers: { "Content-Type": "application/json", ...authHeaders() },
      body: JSON.stringify({ kind: "plan", request }) });
    if (r.status !== 202) {
      throw new Error((validationMessages(r.body, list) || [errorText(r.status, r.body)]).join("\n"));
    }
    state.list = list;
    state.request = request;
    sessionStorage.setItem("mxs-job", JSON.stringify({ id: r.body.job_id, list, request }));
    await followJob(r.body.job_id, false);
  } catch (e) {
    showError(e.message);
    setStatus("", null);
  } finally {
    state.running = false;
    $("go").disabled = false;
  }
}

function setStatus(text, progress, jobState) {
  $("status").textContent = text;
  $("status").dataset.state = jobState || "";
  const bar = $("progress");
  bar.hidden = progress === null;
  if (progress !== null) bar.value = progress;
}

// Poll a plan job until it ends; `restored`: the job of a plan made before a reload.
async function followJob(jobId, restored) {
  setJob(jobId);
  try {
    for (;;) {
      const r = await fetchJson("v1/jobs/" + encodeURIComponent(jobId), { headers: authHeaders() });
      if (r.status !== 200) throw new Error(`job ${jobId}: ${errorText(r.status, r.body)}`);
      const job = r.body;
      setStatus(progressText(job), job.status === "cancelled" ? null : job.progress, job.status);
      if (job.status === "done") {
        showResult(job.result, state.request, state.list,
          { name: state.list.filename, finishedAt: job.updated_at, restored });
        state.resultText = rawMember(r.text, "result");  // the plan file as the server wrote it
        return;
      }
      if (job.status === "failed") throw new Error(`the plan failed: ${job.error}`);
      if (job.status === "cancelled") return;
      await new Promise((res) => setTimeout(res, 500));
    }
  } finally {
    setJob(null);
  }
}

// The job being followed (null: none); the Cancel button works only while there is one. Its
// id stays in a small detail beside the status.
function setJob(jobId) {
  state.jobId = jobId;
  $("cancel").disabled = jobId === null;
  if (jobId !== null) { $("job-id").textContent = `job ${jobId.slice(0, 8)}`; $("job-id").title = `job ${jobId}`; }
}

// POST v1/jobs/{id}/cancel: the job ends as "cancelled" (409 when it has just finished).
async function cancelJob() {
  const jobId = state.jobId;
  if (!jobId) return;
  $("cancel").disabled = true;
  const r = await fetchJson(`v1/jobs/${encodeURIComponent(jobId)}/cancel`, { method: "POST", headers: authHeaders() });
  if (r.status !== 200 && r.status !== 409) showError(`cancel job ${jobId}: ${errorText(r.status, r.body)}`);
}

// ------------------------------------------------------------------------ the plan

// Where every target ended: {pointing, configuration (0-based), arm} or {pointing, reason}.
function targetFates(result) {
  const fate = new Map();
  for (const p of result.pointings) {
    p.configurations.forEach((c, k) => {
      for (const a of c.assignments) if (a.target_id) fate.set(a.target_id, { pointing: p.id, configuration: k, arm: a.arm });
    });
    for (const u of p.unallocated) if (!fate.has(u.target_id)) fate.set(u.target_id, { pointing: p.id, reason: u.reason });
  }
  // targets in no pointing (excluded ones)
  for (const u of result.unallocated || []) if (!fate.has(u.target_id)) fate.set(u.target_id, { pointing: "", reason: u.reason });
  return fate;
}

// Priority tiers: the distinct priorities, highest first (at most TIER_COLOURS.length; beyond
// that, equal-width bins in log10 priority).
function priorityTiers(priorities) {
  const distinct = [...new Set(priorities)].sort((a, b) => b - a);
  if (distinct.length <= TIER_COLOURS.length) {
    return { label: (p) => String(p), index: (p) => distinct.indexOf(p), names: distinct.map(String) };
  }
  const lo = Math.log10(distinct[distinct.length - 1]), hi = Math.log10(distinct[0]);
  const n = TIER_COLOURS.length, w = (hi - lo) / n || 1;
  const index = (p) => Math.min(n - 1, Math.floor((hi - Math.log10(p)) / w));
  const names = [...Array(n).keys()].map((i) =>
    `${Math.round(10 ** (hi - (i + 1) * w))}-${Math.round(10 ** (hi - i * w))}`);
  return { label: (p) => names[index(p)], index, names };
}

// The plan on the page, first what is read first: where it comes from, the banner, the summary
// beside the sky view, the command line, the pointings with their configurations; then the
// long table of every target (closed) and the raw answer. `origin`: {name, finishedAt (Unix
// s), restored} of the plan.
function showResult(result, request, list, origin = state.origin) {
  state.result = result;
  state.resultText = null;
  state.origin = origin;
  $("result").hidden = false;
  $("result").classList.remove("stale");
  showOrigin(origin, request, false);
  const fate = targetFates(result);
  showBanner(result);
  showSummary(result, request, fate);
  const tiers = priorityTiers(request.targets.map((t) => t.priority));
  const byId = new Map(request.targets.map((t) => [t.id, t]));
  $("sky").replaceChildren(...(result.pointings.length ? [skyView(result, request, tiers, fate)] : []));
  $("cli-line").replaceChildren("The same plan from the command line: ",
    el("code", {}, cliLine(request, (origin && origin.name) || (list && list.filename) || "targets.csv", result.stats)),
    origin && origin.name === "pasted.csv" ? " (the pasted table saved as pasted.csv)" : "");
  $("pointings").replaceChildren(...result.pointings.map((p) => pointingSection(p, request, byId, tiers, list)));
  $("every-target").replaceChildren(everyTarget(request, fate));
  $("raw-json").textContent = JSON.stringify(result, null, 1);
  renderLocks();
  snapToPixels(document.querySelectorAll("#result svg.sky, #result svg.configuration"));
}

// "Plan of m67.csv (150 targets), finished at 02:41:07 on 2026-12-05", saying so when the plan
// is the previous one restored after a reload, or stale because the input has changed.
function showOrigin(origin, request, stale) {
  const box = $("plan-origin");
  if (!origin) { box.replaceChildren(); return; }
  const when = origin.finishedAt ? `, finished at ${clockText(origin.finishedAt)}` : "";
  const what = `${origin.name} (${plural(request.targets.length, "target")})${when}`;
  box.className = "plan-origin" + (stale ? " stale" : origin.restored ? " restored" : "");
  box.textContent = stale ? `Stale: this plan is of the previous input, ${what}. The input has changed since: plan again.` :
    origin.restored ? `Previous plan, restored after a reload: ${what}.` : `Plan of ${what}.`;
}

// Unix seconds as local "hh:mm:ss on yyyy-mm-dd".
function clockText(unixS) {
  const d = new Date(unixS * 1000), two = (n) => String(n).padStart(2, "0");
  return `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())} on ` +
    `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())}`;
}

// The input changed: the plan shown no longer answers it, and says so.
function markStale() {
  if ($("result").hidden || !state.result) return;
  $("result").classList.add("stale");
  showOrigin(state.origin, state.request, true);
}

// No plan shown (a new plan runs, or the new input gave an error); a reload restores none.
function clearResult() {
  $("result").hidden = true;
  $("result").classList.remove("stale");
  state.result = null;
  state.origin = null;
  showOrigin(null);
  sessionStorage.removeItem("mxs-job");
}

// Reasons a not-executable plan's banner lists open; more are folded, so the summary and the
// sky view stay on the first screen.
const BANNER_REASONS = 3;

function showBanner(result) {
  const b = $("banner");
  b.replaceChildren();
  const advice = result.time_limit_advice;
  if (result.executable && advice && advice.pointings_not_planned.length) {
    b.className = "warn";
    b.append(`Planned and executable: ${plural(advice.pointings_planned, "pointing")}; ` +
      `${plural(advice.pointings_not_planned.length, "pointing")} did not fit in the time limit ` +
      `(${advice.pointings_not_planned.join(", ")}).`);
  } else if (result.executable) {
    b.className = "good";
    b.append("Every motion leg of every pointing was planned: the plan is executable.");
  } else {
    b.className = "bad";
    const reasons = el("ul", {}, ...result.reasons.map((r) => el("li", {}, r)));
    b.append("This plan is NOT executable: some motion legs could not be planned. Do not execute the failed legs.",
      result.reasons.length <= BANNER_REASONS ? reasons :
        el("details", {}, el("summary", {}, `the ${result.reasons.length} reasons`), reasons));
  }
  // what the plan left out for its time limit, and the limit the field needs
  const notices = result.notices || [];
  if (notices.length) b.append(el("ul", { class: "notices" }, ...notices.map((n) => el("li", {}, n))));
  b.hidden = false;
}

// Mode fewest-exposures: what the programme optimiser's search kept (its model's variants, the
// pointings it merged, the configurations it emptied into idle arms) and the configurations the
// consolidation after the rounds gave up. Rows for the summary table; none in the other modes.
function programmeRows(s) {
  const rows = [];
  const o = (s.segmentation || {}).optimiser;
  const tried = (o && o.model_variants) || [];
  const kept = tried.find((v) => v.chosen);
  if (kept && kept.complete) {
    const first = tried[0];
    let text = `${plural(kept.exposures, "configuration")} in ${plural(kept.pointings, "pointing")}`;
    if (tried.length > 1) text += ` (best of ${tried.length} searches` +
      (kept === first ? ")" : `; the first: ${first.exposures} in ${first.pointings})`);
    if (o.pointings_merged) text += `; ${plural(o.pointings_merged, "pointing")} merged`;
    if (o.exposures_emptied) text += `; ${plural(o.exposures_emptied, "configuration")} emptied into idle arms`;
    rows.push(["programme optimiser", text]);
  }
  const saved = (s.consolidation || {}).exposures_saved;
  if (saved) rows.push(["configurations emptied after planning", `${saved} (targets onto idle arms)`]);
  return rows;
}

function showSummary(result, request, fate) {
  const s = result.stats || {};
  const n = request.targets.length;
  const allocated = request.targets.filter((t) => fate.get(t.id) && fate.get(t.id).configuration !== undefined);
  const rows = [
    ["targets", n], ["pointings", result.pointings.length],
    ["configurations", result.pointings.reduce((a, p) => a + p.configurations.length, 0)],
    ["targets observed", `${allocated.length} (${pct(allocated.length / n)})`],
    ["priority observed", pct(sumPrio(allocated) / sumPrio(request.targets))],
    ["motion legs not planned", `${s.motion_plans_failed ?? "?"} of ${s.motion_plans ?? "?"}`],
  ];
  if (s.telescope_time) rows.splice(3, 0, ["telescope time (h:mm)", telescopeTimeText(s.telescope_time)]);
  if (s.exposures_lower_bound) rows.splice(3, 0, ["proven lower bound on configurations",
    `${s.exposures_lower_bound} (this plan: ${(s.configurations / s.exposures_lower_bound).toFixed(2)}×)`]);
  const takersFewer = (s.few_target_exposures_explained || 0) - s.few_target_exposures_only_here
    - (s.few_target_exposures_plan_failed || 0);
  if (s.few_target_exposures) rows.push(["configurations observing at most 2 targets",
    `${s.few_target_exposures} (${s.few_target_exposures_only_here} only for targets no other configuration can take` +
    (takersFewer > 0 ? `, ${takersFewer} more for targets only configurations of 1 target can take` : "") +
    ((s.few_target_exposures_plan_failed || 0) > 0
      ? `, ${s.few_target_exposures_plan_failed} more whose targets' moves the consolidation planned and failed` : "") +
    (s.few_target_exposures > (s.few_target_exposures_explained ?? s.few_target_exposures)
      ? `, ${s.few_target_exposures - s.few_target_exposures_explained} with a target another configuration could take` +
        (s.consolidation?.reason ? ` (the consolidation stopped: ${s.consolidation.reason})` : "") : "") + ")"]);
  rows.push(...programmeRows(s));
  for (const [k, label] of [["targets_moved", "targets moved to another configuration"],
    ["legs_via_park", "legs through park"], ["configurations_added", "configurations added"],
    ["targets_dropped", "targets dropped"]]) if (s[k]) rows.push([label, s[k]]);
  for (const [reason, count] of Object.entries(s.unallocated_by_reason || {})) rows.push([`not observed: ${reason}`, count]);
  const byPrio = new Map();
  for (const t of request.targets) {
    const e = byPrio.get(t.priority) || { n: 0, done: 0 };
    e.n += 1; if (fate.get(t.id) && fate.get(t.id).configuration !== undefined) e.done += 1;
    byPrio.set(t.priority, e);
  }
  const tierRows = [...byPrio.entries()].sort((a, b) => b[0] - a[0])
    .map(([p, e]) => [priorityText(p), e.n, e.done, pct(e.done / e.n)]);
  $("summary").replaceChildren(
    table(["", "value"], rows),
    el("h3", {}, "Targets observed per priority"),
    table(["priority", "targets", "observed", "completeness"], tierRows, []));
}

// One row per target of the request, with its position in both forms: where it is observed,
// or why not. Closed: it is long, and read after the pictures.
function everyTarget(request, fate) {
  const rows = request.targets.map((t) => {
    const f = fate.get(t.id) || {};
    const observed = f.configuration !== undefined;
    return [t.id, priorityText(t.priority), raHms(t.ra_deg), decDms(t.dec_deg), t.ra_deg.toFixed(5), t.dec_deg.toFixed(5),
      f.pointing || "", observed ? `c${f.configuration + 1}` : "", observed ? f.arm : "",
      observed ? "" : (f.reason || "not in any pointing")];
  });
  return el("details", { class: "every-target" },
    el("summary", {}, `Every target (${rows.length}): position, pointing, configuration, arm, or why it is not observed`),
    table(["target", "priority", "RA (h:m:s)", "Dec (d:m:s)", "RA [deg]", "Dec [deg]", "pointing", "configuration",
      "arm", "not observed because"], rows, [0, 6, 7, 9]));
}

function sumPrio(ts) { return ts.reduce((a, t) => a + t.priority, 0) || 1; }

// ------------------------------------------------------------------------ downloads

function download(name, text, type) {
  const a = el("a", { href: URL.createObjectURL(new Blob([text], { type })), download: name });
  document.body.append(a);
  a.click();
  a.remove();
}

function csvCell(v) {
  const s = v === null || v === undefined ? "" : String(v);
  return /[",\n]/.test(s) ? `"${s.replace(/"/g, '""')}"` : s;
}

function assignmentsCsv(result, request) {
  const prio = new Map(request.targets.map((t) => [t.id, t.priority]));
  const head = ["pointing", "pointing_ra_deg", "pointing_dec_deg", "configuration", "arm", "kind",
    "target_id", "priority", "theta1_rad", "theta2_rad", "x_mm", "y_mm", "reason", "sky_ra_deg", "sky_dec_deg"];
  const rows = [head];
  for (const p of result.pointings) {
    p.configurations.forEach((c, k) => c.assignments.forEach((a) => rows.push([p.id, p.ra_deg, p.dec_deg, k + 1,
      a.arm, a.kind, a.target_id, a.target_id ? prio.get(a.target_id) : "", a.theta1_rad, a.theta2_rad, a.x_mm, a.y_mm, "",
      a.sky_ra_deg, a.sky_dec_deg])));
    for (const u of p.unallocated) rows.push([p.id, p.ra_deg, p.dec_deg, "", "", "unallocated", u.target_id,
      prio.get(u.target_id), "", "", "", "", u.reason]);
  }
  return rows.map((r) => r.map(csvCell).join(",")).join("\n") + "\n";
}

// Controller commands, one row each; legs counted from 1 like configurations (leg 1: park -> c1).
function commandsCsv(result) {
  const rows = [["pointing", "leg", "leg_status", "arm", "joint", "t_start_s", "from_rad", "to_rad", "speed_rad_s"]];
  for (const p of result.pointings) {
    p.motions.forEach((m, i) => m.trajectories.forEach((tr) => tr.commands.forEach((c) =>
      rows.push([p.id, i + 1, m.status, tr.arm, c.joint, c.t_start_s, c.from_rad, c.to_rad, c.speed_rad_s]))));
  }
  return rows.map((r) => r.map(csvCell).join(",")).join("\n") + "\n";
}

// ------------------------------------------------------------------------ start

async function start() {
  $("go").onclick = runPlan;
  $("cancel").onclick = cancelJob;
  $("clear-file").onclick = usePastedTable;
  $("file").onchange = previewTable;
  $("targets").oninput = usePastedTable;
  $("options").addEventListener("input", optionChanged);
  $("options").addEventListener("change", optionChanged);
  $("finding-image").onchange = chooseFindingImage;
  $("pa-auto").addEventListener("change", syncPaMode);
  $("sky-file").onchange = readSkyFile;
  startLocks();
  startValidation();
  $("dl-json").onclick = () => download("plan.json", state.resultText || JSON.stringify(state.result, null, 1), "application/json");
  $("dl-csv").onclick = () => download("assignments.csv", assignmentsCsv(state.result, state.request), "text/csv");
  $("dl-commands").onclick = () => download("commands.csv", commandsCsv(state.result), "text/csv");
  showInputUsed();
  state.defaults = await planDefaults().catch(() => null);
  if (state.defaults) setControls(state.defaults, state.touched);
  else showError("cannot read the API's defaults from openapi.json: the controls keep the page's own");
  const r = await fetchJson("v1/instrument");
  if (r.status !== 200) { showError("cannot read the instrument: " + errorText(r.status, r.body)); return; }
  state.instrument = r.body;
  $("go").disabled = false;
  document.body.dataset.ready = "true";
  const saved = sessionStorage.getItem("mxs-job");
  if (saved) resumeJob(JSON.parse(saved));
}

// A control the user set: the API's defaults, read while the page loads, leave it alone; the
// plan shown no longer answers the form (the token changes no plan).
function optionChanged(e) {
  if (NOT_PLAN_INPUTS.has(e.target.id) || e.target.closest("#lock-menu")) return;
  state.touched.add(e.target.id);
  markStale();
}

// The sky image under the pictures: handed to the viewer (setFindingImage, when it has one).
function chooseFindingImage() {
  const file = $("finding-image").files[0] || null;
  if (typeof setFindingImage === "function") setFindingImage(file);
}

// The plan of the job started before a reload: its controls shown again, labelled as the
// previous plan with its input's name.
async function resumeJob(saved) {
  state.list = saved.list;
  state.request = saved.request;
  setControls(saved.request);
  setLockState(saved.request);
  state.running = true;
  $("go").disabled = true;
  try { await followJob(saved.id, true); } catch (e) {
    sessionStorage.removeItem("mxs-job");
    showError(e.message);
    setStatus("", null);
  } finally {
    state.running = false;
    $("go").disabled = false;
  }
}

window.mxs = { showResult, showBanner, describeLoc, projectTargets, armJoints, anglesAt, assignmentsCsv, commandsCsv, planRequest,
  cliLine, progressText, CONTROLS, state, parseSkyLine, parseAngle, keptConfigurations, locks, lockFields, showValidation,
  atObsDate };
start();
