// MXS planner page: the pictures (drawn in the browser from the API's answers). Loaded
// before app.js; its functions are called once both are loaded.
"use strict";

const SVG_NS = "http://www.w3.org/2000/svg";
const TIER_COLOURS = ["#d62728", "#ff7f0e", "#b8a000", "#2ca02c", "#17becf", "#1f77b4", "#9467bd"];

// ------------------------------------------------------------------------ DOM helpers

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "class") node.className = v; else if (k.startsWith("on")) node[k] = v; else node.setAttribute(k, v);
  }
  for (const c of children) if (c !== null && c !== undefined) node.append(c);
  return node;
}

function svg(tag, attrs, ...children) {
  const node = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, v);
  for (const c of children) if (c !== null && c !== undefined) node.append(c);
  return node;
}

function table(head, rows, leftCols) {
  const left = new Set(leftCols || [0]);
  const th = head.map((h, i) => el("th", { class: left.has(i) ? "l" : "" }, h));
  const trs = rows.map((r) => el("tr", {}, ...r.map((v, i) => el("td", { class: left.has(i) ? "l" : "" }, String(v)))));
  return el("table", {}, el("thead", {}, el("tr", {}, ...th)), el("tbody", {}, ...trs));
}

function pct(x) { return (100 * x).toFixed(1) + " %"; }

// Seconds as h:mm, rounded to the minute.
function hoursMinutes(s) {
  const m = Math.round(s / 60);
  return `${Math.floor(m / 60)}:${String(m % 60).padStart(2, "0")}`;
}

// A plan's or a pointing's stats.telescope_time: total, then exposures + acquisitions + reconfiguration.
function telescopeTimeText(t) {
  const plural = (n, w) => `${n} ${w}${n === 1 ? "" : "s"}`;
  return `${hoursMinutes(t.total_s)} = ${plural(t.exposures, "exposure")} ${hoursMinutes(t.exposure_s)} + ` +
    `${plural(t.acquisitions, "acquisition")} ${hoursMinutes(t.acquisition_s)} + reconfiguration ` +
    `${hoursMinutes(t.reconfiguration_s)}` + (t.unplanned_legs ? ` (${plural(t.unplanned_legs, "leg")} not planned, not counted)` : "");
}

// ------------------------------------------------------------------------ one pointing

function pointingSection(p, request, byId, tiers, list) {
  const sec = el("div", { class: "pointing" + (p.executable ? "" : " not-executable"), "data-pointing": p.id });
  const nAlloc = p.configurations.reduce((a, c) => a + c.assignments.filter((x) => x.target_id).length, 0);
  sec.append(el("h3", {}, `Pointing ${p.id}: RA ${p.ra_deg.toFixed(5)}°, Dec ${p.dec_deg.toFixed(5)}° `,
    el("span", { class: "badge " + (p.executable ? "ok" : "failed") }, p.executable ? "executable" : "NOT executable")),
  el("p", {}, `${p.target_ids.length} targets, ${p.configurations.length} configurations, ${nAlloc} observed, ` +
    `${p.unallocated.length} not observed.`));
  const t = p.stats && p.stats.telescope_time;
  if (t) sec.append(el("p", { class: "telescope-time" }, `Telescope time (h:mm): ${telescopeTimeText(t)}.`));
  if (p.reasons.length) sec.append(el("ul", { class: "changes" }, ...p.reasons.map((r) => el("li", { class: "failed" }, r))));
  if (p.changes.length) {
    sec.append(el("p", {}, el("span", { class: "badge changed" }, "changed"),
      " The motion planner changed the allocation so that the legs can be executed:"),
    el("ul", { class: "changes" }, ...p.changes.map((c) => el("li", {}, `leg ${c.leg}: ${c.kind} - ${c.reason}` +
      (c.target_ids.length ? ` (targets ${c.target_ids.join(", ")})` : "")))));
  }
  const members = p.target_ids.map((id) => byId.get(id)).filter(Boolean);
  const pos = projectTargets(members, p, request.position_angle_deg);
  if (p.configurations.length) sec.append(configurationViewer(p, members, pos, tiers));
  sec.append(targetTable(p, members));
  return sec;
}

// Gnomonic (TAN) projection about the pointing, as models/sky.py: +xi East, +eta North,
// the focal-plane +y axis at position angle PA East of North.
function projectTargets(members, p, paDeg) {
  const scaleDegPerMm = state.instrument.plate_scale_arcsec_per_mm / 3600, pa = paDeg * Math.PI / 180;
  const out = new Map();
  for (const t of members) {
    const [xi, eta] = standardCoords(t.ra_deg, t.dec_deg, p.ra_deg, p.dec_deg);
    out.set(t.id, { x: (xi * Math.cos(pa) - eta * Math.sin(pa)) / scaleDegPerMm,
                    y: (xi * Math.sin(pa) + eta * Math.cos(pa)) / scaleDegPerMm });
  }
  return out;
}

// Standard coordinates (xi East, eta North; deg) of a sky position about a tangent point.
function standardCoords(raDeg, decDeg, ra0Deg, dec0Deg) {
  const d2r = Math.PI / 180, ra = raDeg * d2r, de = decDeg * d2r, ra0 = ra0Deg * d2r, de0 = dec0Deg * d2r;
  const cosc = Math.sin(de0) * Math.sin(de) + Math.cos(de0) * Math.cos(de) * Math.cos(ra - ra0);
  return [Math.cos(de) * Math.sin(ra - ra0) / cosc / d2r,
          (Math.cos(de0) * Math.sin(de) - Math.sin(de0) * Math.cos(de) * Math.cos(ra - ra0)) / cosc / d2r];
}

function targetTable(p, members) {
  const where = new Map();
  p.configurations.forEach((c, k) => c.assignments.forEach((a) => { if (a.target_id) where.set(a.target_id, [`c${k + 1}`, a.arm, ""]); }));
  for (const u of p.unallocated) if (!where.has(u.target_id)) where.set(u.target_id, ["", "", u.reason]);
  const rows = members.map((t) => [t.id, t.priority, ...(where.get(t.id) || ["", "", "?"])]);
  return el("details", { class: "targets" }, el("summary", {}, `Targets of pointing ${p.id}`),
    table(["target", "priority", "configuration", "arm", "not observed because"], rows, [0, 4]));
}

// ------------------------------------------------------------------------ configuration viewer

function configurationViewer(p, members, pos, tiers) {
  const box = el("div", { class: "viewer-box" });
  const stepper = el("div", { class: "stepper" }, "Configuration: ");
  const view = el("div", { class: "viewer" });
  const legInfo = el("p", { class: "leg" });
  const show = (k) => {
    for (const b of stepper.querySelectorAll("button")) b.setAttribute("aria-pressed", String(Number(b.dataset.k) === k));
    view.replaceChildren(drawConfiguration(p, k, members, pos, tiers), legend(tiers));
    legInfo.replaceChildren(...legText(p, k));
  };
  let current = 0;
  p.configurations.forEach((c, k) => {
    const flag = legFlag(p, k);
    stepper.append(el("button", { type: "button", "data-k": k, class: flag,
      title: `${c.arm_yield} arms, priority ${c.total_priority}` + (flag === "failed" ? "; its motion leg was NOT planned" :
        flag === "changed" ? "; changed by the motion planner" : ""),
      onclick: () => { current = k; show(k); } }, `c${k + 1}` + (flag === "failed" ? " ✗" : flag === "changed" ? " *" : "")));
  });
  const play = el("button", { type: "button", class: "play", title: "animate the motion leg into this configuration",
    onclick: () => playLeg(p, current, view, legInfo, () => show(current)) }, "▶ play the leg into it");
  const save = el("button", { type: "button", class: "save-svg", title: "this picture as an SVG file",
    onclick: () => savePicture(view.querySelector("svg"), `pointing${p.id}_c${current + 1}.svg`) }, "download picture (SVG)");
  box.append(stepper, play, " ", save, legInfo, view);
  show(0);
  return box;
}

// "failed" when a motion leg into or out of configuration k was not planned, "changed" when the
// motion planner changed it (the pointing's `changes`), "" otherwise.
function legFlag(p, k) {
  const last = k === p.configurations.length - 1;
  const legOk = (i) => !p.motions[i] || p.motions[i].status === "ok";
  if (!legOk(k) || (last && !legOk(k + 1))) return "failed";
  if (p.changes.some((c) => c.configuration === k || c.leg === k)) return "changed";
  return "";
}

function savePicture(root, name) {
  const copy = root.cloneNode(true);
  copy.setAttribute("xmlns", SVG_NS);
  copy.setAttribute("width", "800");
  copy.setAttribute("height", "800");
  download(name, new XMLSerializer().serializeToString(copy), "image/svg+xml");
}

// Joint angles of every arm at time t_s of a motion leg (piecewise linear between waypoints).
function anglesAt(motion, t) {
  const out = new Map();
  for (const tr of motion.trajectories) {
    const w = tr.waypoints;
    if (!w.length) continue;
    let i = 0;
    while (i < w.length - 1 && w[i + 1].t_s <= t) i++;
    const a = w[i], b = w[Math.min(i + 1, w.length - 1)];
    const f = b.t_s > a.t_s ? Math.min(1, Math.max(0, (t - a.t_s) / (b.t_s - a.t_s))) : 0;
    out.set(tr.arm, [a.theta1_rad + f * (b.theta1_rad - a.theta1_rad), a.theta2_rad + f * (b.theta2_rad - a.theta2_rad)]);
  }
  return out;
}

function playLeg(p, k, view, legInfo, done) {
  const motion = p.motions[k], root = view.querySelector("svg");
  if (!motion || !root || root.dataset.playing) return;
  const goal = new Map(p.configurations[k].assignments.map((a) => [a.arm, a]));
  const end = Math.max(motion.makespan_s || 0, ...motion.trajectories.flatMap((t) => t.waypoints.map((w) => w.t_s)), 0);
  const wallMs = Math.min(4000, Math.max(1000, end * 30));
  const clock = el("span", { class: "clock" });
  legInfo.append(" ", clock);
  root.dataset.playing = "true";
  const t0 = performance.now();
  const frame = (now) => {
    const t = Math.min(end, (now - t0) / wallMs * end);
    const angles = anglesAt(motion, t), arms = svg("g", { class: "arms" });
    for (const arm of state.instrument.arms) {
      const q = angles.get(arm.arm) || [goal.get(arm.arm).theta1_rad, goal.get(arm.arm).theta2_rad];
      arms.append(drawArm(arm, { ...goal.get(arm.arm), theta1_rad: q[0], theta2_rad: q[1] }));
    }
    root.querySelector("g.arms").replaceWith(arms);
    clock.textContent = `t = ${t.toFixed(0)} s of ${end.toFixed(0)} s`;
    if (t < end) requestAnimationFrame(frame); else { delete root.dataset.playing; done(); }
  };
  requestAnimationFrame(frame);
}

// ------------------------------------------------------------------------ the field on the sky

// Targets and pointings about the field's tangent point, North up and East left (arcmin).
function skyView(result, request, tiers, fate) {
  const tp = result.tangent_point || result.pointings[0];
  const rArcmin = state.instrument.fov_diameter_mm / 2 * state.instrument.plate_scale_arcsec_per_mm / 60;
  const sky = (ra, dec) => { const [xi, eta] = standardCoords(ra, dec, tp.ra_deg, tp.dec_deg); return [-60 * xi, -60 * eta]; };
  const pts = request.targets.map((t) => sky(t.ra_deg, t.dec_deg));
  const centres = result.pointings.map((p) => sky(p.ra_deg, p.dec_deg));
  const half = 1.15 * Math.max(rArcmin, ...pts.map(([x, y]) => Math.max(Math.abs(x), Math.abs(y))),
    ...centres.map(([x, y]) => Math.max(Math.abs(x), Math.abs(y)) + rArcmin));
  const root = svg("svg", { viewBox: `${-half} ${-half} ${2 * half} ${2 * half}`, class: "sky", role: "img",
    "aria-label": "the field on the sky" });
  const u = half / 100;  // one percent of the view, for strokes and text
  result.pointings.forEach((p, i) => root.append(
    svg("circle", { class: "pointing-fov", cx: centres[i][0], cy: centres[i][1], r: rArcmin, fill: "none",
      stroke: p.executable ? "#1f4e99" : "#c62828", "stroke-width": 0.4 * u }),
    svg("text", { x: centres[i][0] + 0.72 * rArcmin, y: centres[i][1] - 0.72 * rArcmin, "font-size": 5 * u }, p.id)));
  request.targets.forEach((t, i) => {
    const f = fate.get(t.id), st = f && f.configuration !== undefined ? "this" : "unallocated";
    root.append(targetMark({ x: 0, y: 0 }, st, TIER_COLOURS[tiers.index(t.priority)],
      { class: "sky-target", transform: `translate(${pts[i][0]},${pts[i][1]}) scale(${0.7 * u})` },
      `${t.id} (priority ${t.priority}): ${st === "this" ? "observed" : "not observed"}`));
  });
  const cx = -0.72 * half, cy = -0.72 * half, L = 0.12 * half;
  const bar = [60, 30, 20, 10, 5, 2, 1, 0.5, 0.2, 0.1].find((b) => b <= half / 2) || 0.1;  // arcmin
  root.append(svg("line", { x1: cx, y1: cy, x2: cx, y2: cy - L, stroke: "#000", "stroke-width": 0.4 * u }),
    svg("text", { x: cx - 2 * u, y: cy - L - 2 * u, "font-size": 6 * u }, "N"),
    svg("line", { x1: cx, y1: cy, x2: cx - L, y2: cy, stroke: "#000", "stroke-width": 0.4 * u }),
    svg("text", { x: cx - L - 6 * u, y: cy + 2 * u, "font-size": 6 * u }, "E"),
    svg("line", { class: "sky-scale", x1: 0.9 * half - bar, y1: 0.9 * half, x2: 0.9 * half, y2: 0.9 * half, stroke: "#000", "stroke-width": 0.6 * u }),
    svg("text", { x: 0.9 * half - bar, y: 0.9 * half - 2 * u, "font-size": 5 * u }, `${bar}′`));
  return el("div", { class: "field" }, el("h3", {}, "The field on the sky"),
    el("p", {}, `North up, East left; circles: the fields of view of the ${result.pointings.length} pointing${result.pointings.length === 1 ? "" : "s"} ` +
      "(red: not executable); filled: observed, crosses: not observed; colour: priority."), root);
}

function legText(p, k) {
  const out = [];
  const legs = [[k, k === 0 ? "park" : `c${k}`, `c${k + 1}`]];
  if (k === p.configurations.length - 1) legs.push([k + 1, `c${k + 1}`, "park"]);
  for (const [i, from, to] of legs) {
    const m = p.motions[i];
    if (!m) continue;
    const ok = m.status === "ok";
    out.push(el("span", { class: "badge " + (ok ? "ok" : "failed") },
      `leg ${i} (${from} -> ${to}): ` + (ok ? `planned, ${m.makespan_s.toFixed(1)} s` : `NOT planned (arms ${m.failed_arms.join(", ")})`)), " ");
  }
  const c = p.configurations[k];
  out.push(`${c.arm_yield} arms on targets, total priority ${c.total_priority}.`);
  return out;
}

// FK of one arm in the FOV frame (models/kinematics.py, thesis eqs. 3.4, 3.9-3.16).
function armJoints(arm, t1, t2) {
  const j3 = [arm.d13_mm * Math.cos(t1), arm.d13_mm * Math.sin(t1)];
  const j4 = [arm.d12_mm - arm.d24_mm * Math.cos(t2), arm.d24_mm * Math.sin(t2)];
  const w = [j4[0] - j3[0], j4[1] - j3[1]], d = Math.hypot(w[0], w[1]);
  const local = { J1: [0, 0], J2: [arm.d12_mm, 0], J3: j3, J4: j4,
                  tip: [j3[0] + arm.d3tip_mm * w[0] / d, j3[1] + arm.d3tip_mm * w[1] / d] };
  const ex = [Math.cos(arm.orientation_rad), Math.sin(arm.orientation_rad)], ey = [-ex[1], ex[0]];
  const out = {};
  for (const [k, [a, b]] of Object.entries(local)) {
    out[k] = [arm.base_x_mm + a * ex[0] + b * ey[0], arm.base_y_mm + a * ex[1] + b * ey[1]];
  }
  return out;
}

function targetStatus(id, k, p) {
  for (let j = 0; j < p.configurations.length; j++) {
    if (p.configurations[j].assignments.some((a) => a.target_id === id)) {
      return j === k ? "this" : j < k ? "earlier" : "pending";
    }
  }
  return "unallocated";
}

function drawConfiguration(p, k, members, pos, tiers) {
  const inst = state.instrument, r = inst.fov_diameter_mm / 2, half = 1.3 * r;
  const root = svg("svg", { viewBox: `${-half} ${-half} ${2 * half} ${2 * half}`, role: "img",
    "aria-label": `pointing ${p.id}, configuration ${k + 1}`, "data-configuration": k + 1 });
  const g = svg("g", { transform: "scale(1,-1)" });  // focal plane: +x right, +y up
  g.append(svg("circle", { cx: 0, cy: 0, r, fill: "#fafafa", stroke: "#555", "stroke-width": 0.8, "stroke-dasharray": "4 3", class: "fov" }));
  const c = p.configurations[k];
  const arms = svg("g", { class: "arms" });
  for (const a of c.assignments) {
    const arm = inst.arms.find((x) => x.arm === a.arm);
    if (arm) arms.append(drawArm(arm, a));
  }
  g.append(arms, drawTargets(p, k, members, pos, tiers));
  root.append(g, compass(half, p), scaleBar(half));
  return root;
}

function drawArm(arm, a) {
  const j = armJoints(arm, a.theta1_rad, a.theta2_rad);
  const colour = !arm.enabled ? "#999" : a.target_id ? "#1f4e99" : "#7a8db3";
  const g = svg("g", { class: "arm", "data-arm": a.arm, "data-tip-x": j.tip[0], "data-tip-y": j.tip[1] });
  for (const b of arm.bodies) {
    const p0 = j[b.joint_from], p1 = j[b.joint_to];
    if (!p0 || !p1) continue;
    const width = b.shape === "capsule" ? 2 * b.radius_mm : (b.width_mm || 2 * b.radius_mm || 10);
    g.append(svg("line", { x1: p0[0], y1: p0[1], x2: p1[0], y2: p1[1], stroke: colour, "stroke-opacity": 0.4,
      "stroke-width": width, "stroke-linecap": b.shape === "capsule" ? "round" : "butt" }));
  }
  g.append(svg("circle", { cx: j.tip[0], cy: j.tip[1], r: 1.5, fill: colour }));
  const label = svg("text", { x: j.tip[0] - 6, y: -(j.tip[1] - 9), "font-size": 6, fill: colour, transform: "scale(1,-1)" }, `arm ${a.arm}`);
  g.append(svg("title", {}, `arm ${a.arm}: ${a.kind || ""} ${a.target_id || ""}`), label);
  return g;
}

function drawTargets(p, k, members, pos, tiers) {
  const g = svg("g", { class: "targets" });
  for (const t of members) {
    const q = pos.get(t.id), st = targetStatus(t.id, k, p);
    const colour = TIER_COLOURS[tiers.index(t.priority)];
    const attrs = { class: `target ${st}`, "data-id": t.id, "data-status": st, "data-x": q.x, "data-y": q.y };
    g.append(targetMark(q, st, colour, attrs, `${t.id} (priority ${t.priority}): ${statusText(st, k)}`));
    if (st === "this" || st === "pending") {
      g.append(svg("text", { x: q.x + 3.5, y: -q.y + 1.5, "font-size": 6, fill: "#333", transform: "scale(1,-1)" }, t.id));
    }
  }
  return g;
}

function statusText(st, k) {
  return { this: `observed in configuration ${k + 1}`, earlier: "observed in an earlier configuration",
    pending: "observed in a later configuration", unallocated: "not observed" }[st];
}

function targetMark(q, st, colour, attrs, title) {
  let node;
  if (st === "this") node = svg("circle", { ...attrs, cx: q.x, cy: q.y, r: 3, fill: colour, stroke: "#000", "stroke-width": 0.6 });
  else if (st === "pending") node = svg("circle", { ...attrs, cx: q.x, cy: q.y, r: 2.6, fill: "#fff", stroke: colour, "stroke-width": 1.2 });
  else if (st === "earlier") node = svg("circle", { ...attrs, cx: q.x, cy: q.y, r: 1.6, fill: "#bbb", stroke: "none" });
  else node = svg("path", { ...attrs, d: `M${q.x - 2.5},${q.y - 2.5}L${q.x + 2.5},${q.y + 2.5}M${q.x - 2.5},${q.y + 2.5}L${q.x + 2.5},${q.y - 2.5}`, stroke: colour, "stroke-width": 1 });
  node.append(svg("title", {}, title));
  return node;
}

// N and E arrows: +eta (North) is (-sin PA, cos PA) and +xi (East) (cos PA, sin PA) on the
// focal plane (models/sky.py).
function compass(half, p) {
  const pa = (state.request.position_angle_deg || 0) * Math.PI / 180, L = 0.12 * half;
  const cx = -0.8 * half, cy = 0.75 * half;  // the compass centre, top left
  const g = svg("g", { class: "compass" });
  for (const [name, v] of [["N", [-Math.sin(pa), Math.cos(pa)]], ["E", [Math.cos(pa), Math.sin(pa)]]]) {
    const x2 = cx + L * v[0], y2 = -cy - L * v[1];
    g.append(svg("line", { x1: cx, y1: -cy, x2, y2, stroke: "#000", "stroke-width": 1 }),
      svg("text", { x: cx + 1.35 * L * v[0] - 2.5, y: -cy - 1.35 * L * v[1] + 2.5, "font-size": 8 }, name));
  }
  g.append(svg("text", { x: -half + 4, y: half - 4, "font-size": 7 }, `PA ${(state.request.position_angle_deg || 0).toFixed(1)}°`));
  return g;
}

function scaleBar(half) {
  const arcsec = 60, mm = arcsec / state.instrument.plate_scale_arcsec_per_mm;
  const x0 = half - 8 - mm, y = half - 10;
  return svg("g", { class: "scale-bar" },
    svg("line", { x1: x0, y1: y, x2: x0 + mm, y2: y, stroke: "#000", "stroke-width": 1.2 }),
    svg("text", { x: x0, y: y - 3, "font-size": 7 }, `${arcsec}″ (${mm.toFixed(0)} mm)`));
}

function legend(tiers) {
  const mark = (st, colour) => {
    const s = svg("svg", { viewBox: "-5 -5 10 10" });
    s.append(targetMark({ x: 0, y: 0 }, st, colour, {}, ""));
    return s;
  };
  return el("ul", { class: "legend" },
    el("li", {}, mark("this", "#888"), " observed in this configuration (colour: priority)"),
    el("li", {}, mark("pending", "#888"), " pending: observed in a later configuration"),
    el("li", {}, mark("earlier", "#888"), " observed in an earlier configuration"),
    el("li", {}, mark("unallocated", "#888"), " not observed"),
    ...tiers.names.map((n, i) => el("li", {}, mark("this", TIER_COLOURS[i]), ` priority ${n}`)));
}
