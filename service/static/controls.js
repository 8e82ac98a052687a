// MXS planner page: the observation controls of issue 39 that are not one plain field each:
// the position angle searched ("auto", with a range and a step), the sky positions for spare
// arms (typed or read from a file, decimal or sexagesimal) and the targets' positions at the
// observation date for drawing. Loaded after format.js and before form.js, which calls
// extraFields, setExtraControls and extraFlags when it builds a request or a command line.
"use strict";

// Target fields of SkyTarget beyond id, position and priority, passed on as the table gives them
// (the server propagates the targets to obs_date with them).
const MOTION_FIELDS = ["pmra_mas_yr", "pmdec_mas_yr", "parallax_mas", "radial_velocity_km_s", "ref_epoch_yr"];

// ------------------------------------------------------------------------ position angle

// Enable the controls of the mode chosen: the fixed angle, or the search's range and step.
function syncPaMode() {
  const auto = document.getElementById("pa-auto").checked;
  document.getElementById("pa").disabled = auto;
  for (const id of ["pa-min", "pa-max", "pa-step"]) document.getElementById(id).disabled = !auto;
}

// The position-angle fields of the form: "auto" with its optional range [min, max] and step,
// or nothing (the fixed angle is the plain control "pa"). A range needs both ends.
function paFields() {
  if (!document.getElementById("pa-auto").checked) return {};
  const num = (id) => { const v = document.getElementById(id).value.trim(); return v === "" ? null : Number(v); };
  const out = { position_angle_deg: "auto" };
  const lo = num("pa-min"), hi = num("pa-max"), step = num("pa-step");
  if ((lo === null) !== (hi === null)) throw new Error("position angle range: give both ends, or neither (any angle)");
  if (lo !== null) out.position_angle_range_deg = [lo, hi];
  if (step !== null) out.position_angle_step_deg = step;
  return out;
}

// ------------------------------------------------------------------------ sky positions

// An angle written in decimal or sexagesimal ("16:41:41.7", "16 41 41.7", "16h41m41.7s",
// "+36d27m41s", "+36°27′41″"); `hours`: a sexagesimal value is in hours (RA). NaN if unreadable.
function parseAngle(text, hours) {
  const s = text.trim();
  if (/^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$/.test(s)) return Number(s);
  const m = s.match(/^([-+−]?)(\d+)[\s:hd°]+(\d+)[\s:m′']+(\d+\.?\d*)[s″"]?$/);
  if (!m) return NaN;
  const [a, b, c] = [Number(m[2]), Number(m[3]), Number(m[4])];
  if (b >= 60 || c >= 60) return NaN;
  const value = (a + b / 60 + c / 3600) * (hours ? 15 : 1);
  return m[1] === "-" || m[1] === "−" ? -value : value;
}

// One sky position from a line: "RA Dec" (decimal degrees, or RA in hours and Dec in degrees,
// sexagesimal with colons, spaces or letters), comma, tab or spaces between them.
function parseSkyLine(line) {
  const t = line.trim();
  let parts = t.split(/\s*[,;\t]\s*/);
  if (parts.length !== 2) {
    const w = t.split(/\s+/);
    if (w.length === 2) parts = w;
    else if (w.length === 6) parts = [w.slice(0, 3).join(" "), w.slice(3).join(" ")];
    else return null;
  }
  const sexagesimal = !/^[+-]?[\d.]+([eE][+-]?\d+)?$/.test(parts[0].trim());
  const ra = parseAngle(parts[0], sexagesimal), dec = parseAngle(parts[1], false);
  if (!Number.isFinite(ra) || !Number.isFinite(dec) || dec < -90 || dec > 90) return null;
  return { ra_deg: ra >= 0 && ra < 360 ? ra : ((ra % 360) + 360) % 360, dec_deg: dec };  // as written when in [0, 360)
}

// The sky positions typed (one per line; empty lines and lines starting with # skipped), or
// null when there are none; an unreadable line is an error naming it.
function skyPositions() {
  const lines = document.getElementById("sky-positions").value.split(/\r?\n/);
  const out = [];
  lines.forEach((line, i) => {
    if (!line.trim() || line.trim().startsWith("#")) return;
    const p = parseSkyLine(line);
    if (!p) throw new Error(`sky positions, line ${i + 1}: '${line.trim()}' is not 'RA Dec' ` +
      "(decimal degrees, or RA h:m:s and Dec d:m:s)");
    out.push(p);
  });
  return out.length ? out : null;
}

// A text file of sky positions replaces the typed ones (read here: nothing is uploaded).
async function readSkyFile() {
  const file = document.getElementById("sky-file").files[0];
  if (!file) return;
  const box = document.getElementById("sky-positions");
  box.value = (await file.text()).split(/\r?\n/).filter((l) => !/^\s*[A-Za-z_]/.test(l)).join("\n");  // no header
  box.dispatchEvent(new Event("input", { bubbles: true }));
}

// ------------------------------------------------------------------------ the request

// The fields of issue 39 that the form adds to a PlanRequest: the position-angle search, the sky
// positions, the locks, exclusions and kept configurations (locks.js). Errors name the control.
function extraFields() {
  const out = paFields();
  const sky = skyPositions();
  if (sky) out.sky_positions = sky;
  if (typeof lockFields === "function") Object.assign(out, lockFields());
  return out;
}

// A target of a table as the request sends it: its motion fields when the table has them.
function requestTarget(t) {
  const out = { id: t.id, ra_deg: t.ra_deg, dec_deg: t.dec_deg, priority: t.priority };
  for (const k of MOTION_FIELDS) if (t[k] !== null && t[k] !== undefined) out[k] = t[k];
  return out;
}

// Set the position-angle search and the sky positions from a request (the API's defaults, or
// the request of a plan restored after a reload); the locks are set by setLockState.
function setExtraControls(values) {
  const auto = values.position_angle_deg === "auto";
  document.getElementById("pa-auto").checked = auto;
  const range = values.position_angle_range_deg;
  document.getElementById("pa-min").value = auto && range ? String(range[0]) : "";
  document.getElementById("pa-max").value = auto && range ? String(range[1]) : "";
  document.getElementById("pa-step").value = auto && values.position_angle_step_deg != null ? String(values.position_angle_step_deg) : "";
  syncPaMode();
  if ("sky_positions" in values) {
    document.getElementById("sky-positions").value = (values.sky_positions || [])
      .map((p) => `${p.ra_deg} ${p.dec_deg}`).join("\n");
  }
}

// The `mxs-planner plan` words of the fields above (the plain controls are form.js's).
function extraFlags(request) {
  const words = [];
  const range = request.position_angle_range_deg;
  if (range) words.push("--position-angle-range", String(range[0]), String(range[1]));
  if (request.position_angle_step_deg != null) words.push("--position-angle-step", String(request.position_angle_step_deg));
  for (const l of request.locked || []) {
    words.push("--lock", shellWord(`${l.target_id}:${l.arm}` + (l.branch === null || l.branch === undefined ? "" : `:${l.branch}`)));
  }
  for (const id of request.excluded_targets || []) words.push("--exclude", shellWord(id));
  if (request.keep_configurations && typeof keepFlag === "function") words.push("--keep", shellWord(keepFlag()));
  if (request.sky_positions) words.push("--sky", "sky.csv");  // the sky positions saved as sky.csv
  return words;
}

// ------------------------------------------------------------------------ epochs, for drawing

// Julian year of an ISO date "YYYY-MM-DD" (J2000.0 = 2000-01-01T12:00 TT; the half day and
// TT-UTC are far below a drawing's scale).
function julianYear(isoDate) {
  const ms = Date.parse(isoDate + "T12:00:00Z");
  return 2000 + (ms - Date.parse("2000-01-01T12:00:00Z")) / (365.25 * 86400e3);
}

// A target where it is on the request's obs_date, for drawing: moved linearly by its proper
// motion from its catalogue epoch (J2000.0 when not given). The server propagates with astropy
// (apply_space_motion); over decades the two differ by far less than a marker.
function atObsDate(t, request) {
  if (!request.obs_date || (!t.pmra_mas_yr && !t.pmdec_mas_yr)) return t;
  const years = julianYear(request.obs_date) - (t.ref_epoch_yr || 2000);
  const cosDec = Math.cos(t.dec_deg * Math.PI / 180) || 1e-9;
  return { ...t, ra_deg: t.ra_deg + (t.pmra_mas_yr || 0) * years / 3.6e6 / cosDec,
    dec_deg: t.dec_deg + (t.pmdec_mas_yr || 0) * years / 3.6e6 };
}
