// MXS planner page: the plan form. Each control is one PlanRequest field and one flag of
// `mxs-planner plan`, so the page builds the request, starts from the API's defaults (read from
// /openapi.json, so the page and the API cannot disagree) and writes the equivalent command line.
// Loaded after format.js and before app.js.
"use strict";

// The plan form: element id, PlanRequest field, `mxs-planner plan` flag; `number`: sent as a number.
const CONTROLS = [
  { id: "method", field: "method", flag: "--method" },
  { id: "solver", field: "solver", flag: "--solver" },
  { id: "pa", field: "position_angle_deg", flag: "--position-angle", number: true },
  { id: "segmentation", field: "segmentation_mode", flag: "--segmentation-mode" },
  { id: "time-limit", field: "time_limit_s", flag: "--time-limit", number: true },
  { id: "seed", field: "seed", flag: "--seed", number: true },
  { id: "park-limit", field: "park_move_limit_s", flag: "--park-move-limit", number: true },
  { id: "exposure-time", field: "exposure_time_s", flag: "--exposure-time", number: true },
  { id: "acquisition", field: "acquisition_s", flag: "--acquisition", number: true },
  { id: "max-exposures", field: "max_exposures", flag: "--max-exposures", number: true },
  { id: "min-priority", field: "min_priority_per_exposure", flag: "--min-priority-per-exposure", number: true },
  { id: "min-targets", field: "min_targets_per_exposure", flag: "--min-targets-per-exposure", number: true },
  { id: "obs-date", field: "obs_date", flag: "--obs-date" },
  { id: "sky-radius", field: "sky_radius_arcsec", flag: "--sky-radius", number: true },
];

// PlanRequest's default of every control, from the API's own OpenAPI document (a field without
// a "default" defaults to null). null when the document cannot be read.
async function planDefaults() {
  const r = await fetch("openapi.json");
  if (!r.ok) return null;
  const doc = await r.json();
  const props = doc && doc.components && doc.components.schemas && doc.components.schemas.PlanRequest &&
    doc.components.schemas.PlanRequest.properties;
  if (!props) return null;
  return Object.fromEntries(CONTROLS.map((c) => [c.field, props[c.field] && "default" in props[c.field] ?
    props[c.field].default : null]));
}

// Set the controls to the fields of `values` (a PlanRequest-like object); a field it lacks
// leaves its control as it is, null empties it (park_move_limit_s null: "no limit" ticked).
// Controls whose id is in `skip` (the user has set them) are left as they are.
function setControls(values, skip = new Set()) {
  for (const c of CONTROLS) {
    if (!(c.field in values) || skip.has(c.id) || (c.id === "park-limit" && skip.has("park-unlimited"))) continue;
    const v = values[c.field];
    if (c.field === "park_move_limit_s") {
      document.getElementById("park-unlimited").checked = v === null;
      if (v === null) continue;
    }
    if (c.id === "pa" && typeof v !== "number" && v !== null && v !== undefined) continue;  // "auto": setExtraControls
    document.getElementById(c.id).value = v === null || v === undefined ? "" : String(v);
  }
  if (!skip.has("pa-auto")) setExtraControls(values);
}

// The PlanRequest of the form for a target list; an empty control is left out (the API's default).
// The position-angle search, sky positions, locks and kept configurations come from
// controls.js and locks.js (extraFields); an unreadable one throws an error naming it.
function planRequest(list) {
  const req = { targets: list.targets.map(requestTarget) };
  for (const c of CONTROLS) {
    const v = document.getElementById(c.id).value.trim();
    if (v) req[c.field] = c.number ? Number(v) : v;
  }
  if (document.getElementById("park-unlimited").checked) req.park_move_limit_s = null;
  return Object.assign(req, extraFields());
}

// A word for a POSIX shell: quoted when it holds anything but plain characters.
function shellWord(s) {
  return /^[A-Za-z0-9._\/:=+-]+$/.test(s) ? s : `'${s.replace(/'/g, "'\\''")}'`;
}

// The `mxs-planner plan` command that makes the same request: every field the request sets,
// and the time limit the plan ran with (`stats.time_limit_s`) when the request left it to the server.
function cliLine(request, filename, stats) {
  const words = ["mxs-planner", "plan", shellWord(filename), "--out", "plan"];
  for (const c of CONTROLS) {
    let v = request[c.field];
    if (c.field === "time_limit_s" && v === undefined && stats) v = stats.time_limit_s;
    if (c.field === "park_move_limit_s" && v === null) { words.push("--no-park-move-limit"); continue; }
    if (v !== undefined && v !== null) words.push(c.flag, shellWord(String(v)));
  }
  return words.concat(extraFlags(request)).join(" ");
}

// What a plan job is doing, from its status: the stage the server names (`stage`) or, without
// one, the pointing being planned (`pointings_done` of `pointings_total`), and the part done.
function progressText(job) {
  const part = `${(100 * (job.progress || 0)).toFixed(0)} %`;
  if (job.status === "queued") return "queued: waiting for a worker";
  if (job.status === "cancelled") return "cancelled";
  if (job.status === "failed") return "failed";
  const total = job.pointings_total, done = job.pointings_done || 0;
  if (job.status === "done") return `done: ${total ? plural(total, "pointing") + " planned" : "planned"} (100 %)`;
  let what;
  if (job.stage) what = job.stage;
  else if (!total) what = "segmenting the field into pointings";
  else if (done < total) what = `planning pointing ${done + 1} of ${total}`;
  else what = "planning again the pointings with a leg not yet planned";
  if (job.stage && total && !/\bof\b/.test(job.stage)) what += ` (${done} of ${plural(total, "pointing")} planned)`;
  return `${what} (${part})`;
}
