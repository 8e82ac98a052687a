// MXS planner page: the pictures (drawn in the browser from the API's answers). Loaded
// after format.js and before app.js; its functions are called once all are loaded.
//
// Orientation (docs/orientation.md): every picture shows the sky as the observer sees it,
// North up and East left. The sky view draws standard coordinates xi (East) leftwards and eta
// (North) up; the configuration viewer draws focal-plane +y up and +x leftwards (fpSvg, the one
// place of that mirror), because models/sky.py puts +x East and +y North at PA 0.
"use strict";

const SVG_NS = "http://www.w3.org/2000/svg";
const TIER_COLOURS = ["#d62728", "#ff7f0e", "#b8a000", "#2ca02c", "#17becf", "#1f77b4", "#9467bd"];
const FOCAL_CONVENTION = "Sky as seen: North up, East left (focal-plane +x drawn leftwards)";
const SKY_CONVENTION = "Sky as seen: North up, East left";
const LABEL_FONT = "DejaVu Sans Mono, Liberation Mono, monospace";
// Arm colours by assignment kind (the legend names them).
const ARM_KINDS = { target: ["#1f4e99", "arm on a target"], sky: ["#00897b", "arm on sky (sky subtraction)"],
  park: ["#8a8a8a", "parked arm (square tip)"], blank: ["#8e44ad", "arm on blank sky"],
  fixed: ["#b0b0b0", "disabled arm (left where it is)"] };

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
  return `${hoursMinutes(t.total_s)} = ${plural(t.exposures, "exposure")} ${hoursMinutes(t.exposure_s)} + ` +
    `${plural(t.acquisitions, "acquisition")} ${hoursMinutes(t.acquisition_s)} + reconfiguration ` +
    `${hoursMinutes(t.reconfiguration_s)}` + (t.unplanned_legs ? ` (${plural(t.unplanned_legs, "leg")} not planned, not counted)` : "");
}

// ------------------------------------------------------------------------ geometry

// Focal plane (mm) -> SVG user units: +y up, +x LEFT, so the picture is the sky as seen.
function fpSvg(x, y) { return [-x, -y]; }

// Standard coordinates (arcmin, xi East, eta North) -> SVG user units: East left, North up.
function skySvg(xiArcmin, etaArcmin) { return [-xiArcmin, -etaArcmin]; }

// The position angle a pointing is observed at: its own when the segmentation or the search
// ("auto") chose one, else the request's.
function pointingPa(p, request) {
  if (p.position_angle_deg !== null && p.position_angle_deg !== undefined) return p.position_angle_deg;
  return typeof request.position_angle_deg === "number" ? request.position_angle_deg : 0;
}

// "PA 30.0°", and " (auto)" when the plan searched the pointing's angle.
function paText(p, pa) {
  return `PA ${pa.toFixed(1)}°` + (p.position_angle_search ? " (auto)" : "");
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

// ------------------------------------------------------------------------ one pointing

function pointingSection(p, request, byId, tiers, list) {
  const sec = el("div", { class: "pointing" + (p.executable ? "" : " not-executable"), "data-pointing": p.id });
  const nAlloc = p.configurations.reduce((a, c) => a + c.assignments.filter((x) => x.target_id).length, 0);
  const pa = pointingPa(p, request), search = p.position_angle_search;
  sec.append(el("h3", { title: search ? `angles tried: ${search.tried_deg.join(", ")}°; ${search.objective}` : "" },
    `Pointing ${p.id}: ${radecText(p.ra_deg, p.dec_deg)}, ${paText(p, pa)} `,
    el("span", { class: "badge " + (p.executable ? "ok" : "failed") }, p.executable ? "executable" : "NOT executable")),
  el("p", {}, `${plural(p.target_ids.length, "target")}, ${plural(p.configurations.length, "configuration")}, ` +
    `${nAlloc} observed, ${p.unallocated.length} not observed.`));
  const t = p.stats && p.stats.telescope_time;
  if (t) sec.append(el("p", { class: "telescope-time" }, `Telescope time (h:mm): ${telescopeTimeText(t)}.`));
  if (p.reasons.length) sec.append(el("ul", { class: "changes" }, ...p.reasons.map((r) => el("li", { class: "failed" }, r))));
  if (p.changes.length) {
    sec.append(el("p", {}, el("span", { class: "badge changed" }, "changed"),
      " The motion planner changed the allocation so that the legs can be executed:"),
    el("ul", { class: "changes" }, ...p.changes.map((c) => el("li", {}, `leg ${c.leg + 1}: ${c.kind} - ${c.reason}` +
      (c.target_ids.length ? ` (targets ${c.target_ids.join(", ")})` : "")))));
  }
  const members = p.target_ids.map((id) => byId.get(id)).filter(Boolean);
  const pos = targetPositions(p, members, request, pa);
  if (p.configurations.length) sec.append(configurationViewer(p, members, pos, tiers));
  sec.append(targetTable(p, members), assignmentTable(p));
  return sec;
}

// Focal-plane positions (mm) of a pointing's targets: the server's (`targets`, at the
// observation date) where the plan gives them, else the page's projection.
function targetPositions(p, members, request, pa) {
  const pos = projectTargets(members.map((t) => atObsDate(t, request)), p, pa);
  for (const t of p.targets || []) if (pos.has(t.id)) pos.set(t.id, { x: t.x_mm, y: t.y_mm });
  return pos;
}

// Sky positions of the plan's targets where it is observed: the server's (`targets` of the
// pointings, at the observation date), else the request's moved by atObsDate.
function observedSky(result, request) {
  const at = new Map();
  for (const p of result.pointings) for (const t of p.targets || []) at.set(t.id, t);
  return request.targets.map((t) => at.get(t.id) || atObsDate(t, request));
}

// Every arm of every configuration: what it does (kind: target, sky, park, fixed) and where.
function assignmentTable(p) {
  const rows = p.configurations.flatMap((c, k) => c.assignments.map((a) => [`c${k + 1}`, a.arm,
    a.kind || (a.target_id ? "target" : "park"), a.target_id || "",
    a.sky_ra_deg === null || a.sky_ra_deg === undefined ? "" : `${raHms(a.sky_ra_deg)} ${decDms(a.sky_dec_deg)}`]));
  return el("details", { class: "assignments" }, el("summary", {}, `Arms of pointing ${p.id}: target, sky or park`),
    table(["configuration", "arm", "kind", "target", "sky position"], rows, [0, 2, 3, 4]));
}

function targetTable(p, members) {
  const where = new Map();
  p.configurations.forEach((c, k) => c.assignments.forEach((a) => { if (a.target_id) where.set(a.target_id, [`c${k + 1}`, a.arm, ""]); }));
  for (const u of p.unallocated) if (!where.has(u.target_id)) where.set(u.target_id, ["", "", u.reason]);
  const rows = members.map((t) => [t.id, priorityText(t.priority), ...(where.get(t.id) || ["", "", "?"])]);
  return el("details", { class: "targets" }, el("summary", {}, `Targets of pointing ${p.id}`),
    table(["target", "priority", "configuration", "arm", "not observed because"], rows, [0, 4]));
}

// ------------------------------------------------------------------------ configuration viewer

function configurationViewer(p, members, pos, tiers) {
  const box = el("div", { class: "viewer-box" });
  const stepper = el("div", { class: "stepper" }, "Configuration: ");
  const view = el("div", { class: "viewer" });
  const legInfo = el("p", { class: "leg" });
  const picked = el("p", { class: "picked", "aria-live": "polite", style: "margin: 0.2em 0" });
  const show = (k) => {
    for (const b of stepper.querySelectorAll("button")) b.setAttribute("aria-pressed", String(Number(b.dataset.k) === k));
    const root = drawConfiguration(p, k, members, pos, tiers);
    view.replaceChildren(root, legend(root, tiers));
    snapToPixels([root]);
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
  view.addEventListener("click", (e) => showPicked(e, picked));
  box.append(stepper, play, " ", save, legInfo, view, picked);
  show(0);
  return box;
}

// Pictures start on a whole pixel of the page: a finding chart's raster is then drawn without
// resampling across a pixel boundary (sharp, and where its WCS puts it to the pixel). Each
// picture's top margin takes up the fraction of a pixel the text above it leaves.
function snapToPixels(roots) {
  for (const root of roots) {
    if (!root.isConnected) continue;
    root.style.marginTop = "0px";
    const top = root.getBoundingClientRect().top + window.scrollY;
    const frac = top - Math.floor(top);
    if (frac > 1e-3) root.style.marginTop = `${(1 - frac).toFixed(4)}px`;
  }
}

// A tap or click on a marker or an arm names it (labels left out of a crowded field included).
function showPicked(e, out) {
  const node = e.target.closest && e.target.closest("[data-id], g.arm, .sky-target");
  const title = node && node.querySelector(":scope > title");
  if (title) out.textContent = title.textContent;
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

// The leg into configuration k as an animation; labels are hidden while the arms move.
function playLeg(p, k, view, legInfo, done) {
  const motion = p.motions[k], root = view.querySelector("svg");
  if (!motion || !root || root.dataset.playing) return;
  const goal = new Map(p.configurations[k].assignments.map((a) => [a.arm, a]));
  const end = Math.max(motion.makespan_s || 0, ...motion.trajectories.flatMap((t) => t.waypoints.map((w) => w.t_s)), 0);
  const wallMs = Math.min(4000, Math.max(1000, end * 30));
  const clock = el("span", { class: "clock" });
  legInfo.append(" ", clock);
  root.dataset.playing = "true";
  for (const g of root.querySelectorAll("g.labels")) g.setAttribute("visibility", "hidden");
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

function legText(p, k) {
  const out = [];
  const legs = [[k, k === 0 ? "park" : `c${k}`, `c${k + 1}`]];
  if (k === p.configurations.length - 1) legs.push([k + 1, `c${k + 1}`, "park"]);
  for (const [i, from, to] of legs) {
    const m = p.motions[i];
    if (!m) continue;
    const ok = m.status === "ok";
    out.push(el("span", { class: "badge " + (ok ? "ok" : "failed") },
      `leg ${i + 1} (${from} -> ${to}): ` + (ok ? `planned, ${m.makespan_s.toFixed(1)} s` : `NOT planned (arms ${m.failed_arms.join(", ")})`)), " ");
  }
  const c = p.configurations[k];
  out.push(`${plural(c.arm_yield, "arm")} on targets, total priority ${c.total_priority}.`);
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

// ------------------------------------------------------------------------ configuration picture

// One configuration of a pointing, sky as seen (fpSvg), its labels laid out without overlaps.
function drawConfiguration(p, k, members, pos, tiers) {
  const inst = state.instrument, r = inst.fov_diameter_mm / 2, half = 1.3 * r, pa = pointingPa(p, state.request);
  const root = svg("svg", { viewBox: `${-half} ${-half} ${2 * half} ${2 * half}`, role: "img", class: "configuration",
    "text-rendering": "geometricPrecision",  // text metrics independent of the drawn scale
    "aria-label": `pointing ${p.id}, configuration ${k + 1}`, "data-configuration": k + 1, "data-pa-deg": pa });
  const layer = chartLayer(root, p.ra_deg, p.dec_deg, half * inst.plate_scale_arcsec_per_mm / 60, pa, half);
  root.append(layer, svg("circle", { cx: 0, cy: 0, r, fill: "none", stroke: "#555", "stroke-width": 0.8,
    "stroke-dasharray": "4 3", class: "fov" }));
  const arms = svg("g", { class: "arms" }), armItems = [], obstacles = [];
  for (const a of p.configurations[k].assignments) {
    const arm = inst.arms.find((x) => x.arm === a.arm);
    if (!arm) continue;
    const g = drawArm(arm, a), [tx, ty] = fpSvg(+g.dataset.tipX, +g.dataset.tipY);
    arms.append(g);
    obstacles.push(markerBox(tx, ty, 1.5));
    armItems.push({ id: `arm ${a.arm}`, x: tx, y: ty, r: 1.5, gap: 1, text: `arm ${a.arm}`, fs: 5, colour: g.dataset.colour });
  }
  const targets = drawTargets(p, k, members, pos, tiers);
  const heads = [headerText(`Pointing ${p.id} c${k + 1}: ${raHms(p.ra_deg)} ${decDms(p.dec_deg)}, ${paText(p, pa)}`,
    -half + 3, -half + 7, 5.5), headerText(FOCAL_CONVENTION, -half + 3, -half + 13.5, 5, "convention")];
  const marks = [compass(half, pa, -0.8 * half, -0.68 * half), scaleBar(half)];
  root.append(arms, targets.g, ...heads, ...marks.map((m) => m.node));
  const items = [...targets.items.filter((i) => i.status === "this"), ...armItems,
    ...targets.items.filter((i) => i.status === "pending")];
  const headBoxes = measureTexts(root, ["viewer"], items, heads);
  const placed = placeLabels(items, [...obstacles, ...targets.obstacles, ...headBoxes, ...marks.map((m) => m.box)],
    [-half, -half, half, half]);
  root.insertBefore(labelNodes(placed, "labels"), heads[0]);
  underlay(root);
  return decorateLocks(root);
}

// A fixed line of text in the label font (measured as an obstacle for labels).
function headerText(text, x, y, fs, cls) {
  return svg("text", { x, y, "font-size": fs, "font-family": LABEL_FONT, class: cls || "header" }, text);
}

// Points of a capsule's outline (segment p0-p1, radius r) in SVG units.
function capsulePoints(p0, p1, r) {
  const a = Math.atan2(p1[1] - p0[1], p1[0] - p0[0]), pts = [];
  for (const [c, a0] of [[p1, a - Math.PI / 2], [p0, a + Math.PI / 2]]) {
    for (let i = 0; i <= 8; i++) pts.push([c[0] + r * Math.cos(a0 + Math.PI * i / 8), c[1] + r * Math.sin(a0 + Math.PI * i / 8)]);
  }
  return pts.map(([x, y]) => `${x.toFixed(2)},${y.toFixed(2)}`).join(" ");
}

// One arm: each body as its true outline with a light fill (overlapping outlines of two
// arms do not read as one solid collision), the tip as a dot. Colour by assignment kind.
function drawArm(arm, a) {
  const j = armJoints(arm, a.theta1_rad, a.theta2_rad);
  const kind = !arm.enabled ? "fixed" : a.kind || (a.target_id ? "target" : "park");
  const colour = (ARM_KINDS[kind] || ARM_KINDS.park)[0];
  const g = svg("g", { class: "arm", "data-arm": a.arm, "data-tip-x": j.tip[0], "data-tip-y": j.tip[1],
    "data-kind": `arm-${kind}`, "data-colour": colour });
  for (const b of arm.bodies) {
    if (!j[b.joint_from] || !j[b.joint_to]) continue;
    const p0 = fpSvg(...j[b.joint_from]), p1 = fpSvg(...j[b.joint_to]);
    const r = b.shape === "capsule" ? b.radius_mm : (b.width_mm || 2 * b.radius_mm || 10) / 2;
    g.append(svg("polygon", { class: "body", points: capsulePoints(p0, p1, r), fill: colour, "fill-opacity": 0.1,
      stroke: colour, "stroke-opacity": 0.85, "stroke-width": 0.6, "stroke-linejoin": "round" }));
  }
  const [tx, ty] = fpSvg(...j.tip);
  const onSky = a.sky_ra_deg === null || a.sky_ra_deg === undefined ? "" : ` ${raHms(a.sky_ra_deg)} ${decDms(a.sky_dec_deg)}`;
  g.append(tipMark(kind, tx, ty, colour),
    svg("title", {}, `arm ${a.arm}: ${(ARM_KINDS[kind] || ARM_KINDS.park)[1]}${a.target_id ? " " + a.target_id : ""}${onSky}`));
  return g;
}

// An arm's tip: a dot on a target, a diamond on sky, a square when parked.
function tipMark(kind, x, y, colour) {
  if (kind === "sky") {
    return svg("path", { class: "tip", d: `M${x},${y - 2.2}L${x + 2.2},${y}L${x},${y + 2.2}L${x - 2.2},${y}Z`, fill: "#fff", stroke: colour, "stroke-width": 0.9 });
  }
  if (kind === "park") return svg("rect", { class: "tip", x: x - 1.3, y: y - 1.3, width: 2.6, height: 2.6, fill: colour });
  return svg("circle", { class: "tip", cx: x, cy: y, r: 1.5, fill: colour });
}

// Markers of a pointing's targets in configuration k, and the label items of the targets
// observed now or later (highest priority first).
function drawTargets(p, k, members, pos, tiers) {
  const g = svg("g", { class: "targets" }), items = [], obstacles = [];
  for (const t of members) {
    const q = pos.get(t.id), st = targetStatus(t.id, k, p), tier = tiers.index(t.priority);
    const [x, y] = fpSvg(q.x, q.y), r = MARK_RADIUS[st];
    const attrs = { class: `target ${st}`, "data-id": t.id, "data-status": st, "data-x": q.x, "data-y": q.y,
      "data-kind": `target-${st}`, "data-tier": tier, "data-cx": x, "data-cy": y, "data-r": Math.max(r, 3) };
    g.append(targetMark({ x, y }, st, TIER_COLOURS[tier], attrs,
      `${t.id} (priority ${priorityText(t.priority)}): ${statusText(st, k)}`));
    obstacles.push(markerBox(x, y, r));
    if (st === "this" || st === "pending") items.push({ id: t.id, x, y, r, gap: 0.8, text: t.id, fs: 5, status: st, priority: t.priority });
  }
  items.sort((a, b) => b.priority - a.priority);
  return { g, items, obstacles };
}

function statusText(st, k) {
  return { this: `observed in configuration ${k + 1}`, earlier: "observed in an earlier configuration",
    pending: "observed in a later configuration", unallocated: "not observed" }[st];
}

const MARK_RADIUS = { this: 3.3, pending: 3.2, earlier: 1.6, unallocated: 2.5 };

function targetMark(q, st, colour, attrs, title) {
  let node;
  if (st === "this") node = svg("circle", { ...attrs, cx: q.x, cy: q.y, r: 3, fill: colour, stroke: "#000", "stroke-width": 0.6 });
  else if (st === "pending") node = svg("circle", { ...attrs, cx: q.x, cy: q.y, r: 2.6, fill: "#fff", stroke: colour, "stroke-width": 1.2 });
  else if (st === "earlier") node = svg("circle", { ...attrs, cx: q.x, cy: q.y, r: 1.6, fill: "#bbb", stroke: "none" });
  else node = svg("path", { ...attrs, d: `M${q.x - 2.5},${q.y - 2.5}L${q.x + 2.5},${q.y + 2.5}M${q.x - 2.5},${q.y + 2.5}L${q.x + 2.5},${q.y - 2.5}`, stroke: colour, "stroke-width": 1 });
  node.append(svg("title", {}, title));
  return node;
}

// N and E arrows at (cx, cy): on the focal plane North is (-sin PA, cos PA) and East
// (cos PA, sin PA) (models/sky.py), both drawn through fpSvg like everything else.
function compass(half, paDeg, cx, cy) {
  const pa = paDeg * Math.PI / 180, L = 0.12 * half;
  const g = svg("g", { class: "compass" });
  for (const [name, v] of [["N", [-Math.sin(pa), Math.cos(pa)]], ["E", [Math.cos(pa), Math.sin(pa)]]]) {
    const [dx, dy] = fpSvg(...v);
    g.append(svg("line", { x1: cx, y1: cy, x2: cx + L * dx, y2: cy + L * dy, stroke: "#000", "stroke-width": 1,
      "data-dir": name }),
    svg("text", { x: cx + 1.35 * L * dx - 2.5, y: cy + 1.35 * L * dy + 2.5, "font-size": 8 }, name));
  }
  g.append(svg("text", { x: -half + 4, y: half - 4, "font-size": 7 }, `PA ${paDeg.toFixed(1)}°`));
  return { node: g, box: [cx - 1.6 * L, cy - 1.6 * L, cx + 1.6 * L, cy + 1.6 * L] };
}

function scaleBar(half) {
  const arcsec = 60, mm = arcsec / state.instrument.plate_scale_arcsec_per_mm;
  const x0 = half - 8 - mm, y = half - 10;
  return { node: svg("g", { class: "scale-bar" },
    svg("line", { x1: x0, y1: y, x2: x0 + mm, y2: y, stroke: "#000", "stroke-width": 1.2 }),
    svg("text", { x: x0, y: y - 3, "font-size": 7 }, `${arcsec}″ (${mm.toFixed(0)} mm)`)),
  box: [x0 - 2, y - 12, half, y + 2] };
}

// ------------------------------------------------------------------------ legends

const TARGET_KINDS = {
  "target-this": ["this", "observed in this configuration (colour: priority)"],
  "target-pending": ["pending", "observed in a later configuration"],
  "target-earlier": ["earlier", "observed in an earlier configuration"],
  "target-unallocated": ["unallocated", "not observed"],
  "sky-observed": ["this", "observed target (colour: priority)"],
  "sky-unobserved": ["unallocated", "target not observed"],
};

function legendSwatch(kind) {
  const s = svg("svg", { viewBox: "-5 -5 10 10" });
  if (TARGET_KINDS[kind]) s.append(targetMark({ x: 0, y: 0 }, TARGET_KINDS[kind][0], "#888", {}, ""));
  else if (kind.startsWith("arm-")) {
    const c = ARM_KINDS[kind.slice(4)][0];
    s.append(svg("polygon", { points: capsulePoints([-3.5, 0], [3.5, 0], 1.6), fill: c, "fill-opacity": 0.1, stroke: c, "stroke-width": 0.6 }),
      tipMark(kind.slice(4), -3.5, 0, c));
  } else if (LOCK_KINDS[kind]) {
    return lockSwatch(kind);
  } else if (kind === "sky-position") {
    s.append(skyPositionMark(0, 0, 3.5));
  } else if (kind.startsWith("fov-")) {
    s.append(svg("circle", { r: 4, fill: "none", stroke: kind === "fov-executable" ? "#1f4e99" : "#c62828", "stroke-width": 0.8 }));
  } else s.append(svg("text", { x: -4, y: 3, "font-size": 7 }, "P"));
  return s;
}

const OTHER_KINDS = { "fov-executable": "field of view of a pointing", "fov-not-executable": "field of view of a pointing NOT executable",
  "pointing-label": "pointing id (beside its field)", "sky-position": "sky position given for spare arms" };

// The key of a picture: every kind of mark it holds (data-kind) and its priority tiers.
function legend(root, tiers) {
  const kinds = new Set([...root.querySelectorAll("[data-kind]")].map((n) => n.dataset.kind));
  const order = [...Object.keys(TARGET_KINDS), ...Object.keys(ARM_KINDS).map((k) => `arm-${k}`), ...Object.keys(OTHER_KINDS),
    ...Object.keys(LOCK_KINDS)];
  const text = (k) => (TARGET_KINDS[k] || [])[1] || (k.startsWith("arm-") ? ARM_KINDS[k.slice(4)][1] :
    OTHER_KINDS[k] || LOCK_KINDS[k][1]);
  const present = new Set([...root.querySelectorAll("[data-tier]")].map((n) => Number(n.dataset.tier)));
  const mark = (i) => { const s = svg("svg", { viewBox: "-5 -5 10 10" }); s.append(targetMark({ x: 0, y: 0 }, "this", TIER_COLOURS[i], {}, "")); return s; };
  return el("ul", { class: "legend" },
    ...order.filter((k) => kinds.has(k)).map((k) => el("li", { "data-kind": k }, legendSwatch(k), " " + text(k))),
    ...tiers.names.map((n, i) => present.has(i) ? el("li", { "data-tier": i }, mark(i), ` priority ${n}`) : null),
    el("li", { class: "note" }, "Labels that would overlap are left out: tap or hover a marker for its id."));
}

// ------------------------------------------------------------------------ the field on the sky

// Targets and pointings about the field's tangent point (arcmin), sky as seen (skySvg).
function skyView(result, request, tiers, fate) {
  const tp = result.tangent_point || result.pointings[0];
  const rArcmin = state.instrument.fov_diameter_mm / 2 * state.instrument.plate_scale_arcsec_per_mm / 60;
  const arcmin = (ra, dec) => standardCoords(ra, dec, tp.ra_deg, tp.dec_deg).map((v) => 60 * v);
  const far = ([x, y]) => Math.max(Math.abs(x), Math.abs(y));
  const halfArcmin = 1.15 * Math.max(rArcmin, ...request.targets.map((t) => far(arcmin(t.ra_deg, t.dec_deg))),
    ...result.pointings.map((p) => far(arcmin(p.ra_deg, p.dec_deg)) + rArcmin));
  // SVG units: 1 % of the half width, so text sizes are those of the configuration viewer
  const half = 100, u = 1, k = half / halfArcmin, r = rArcmin * k;
  const sky = (ra, dec) => skySvg(...arcmin(ra, dec).map((v) => k * v));
  const pts = observedSky(result, request).map((t) => sky(t.ra_deg, t.dec_deg));
  const centres = result.pointings.map((p) => sky(p.ra_deg, p.dec_deg));
  const root = svg("svg", { viewBox: `${-half} ${-half} ${2 * half} ${2 * half}`, class: "sky", role: "img",
    "text-rendering": "geometricPrecision",
    "aria-label": "the field on the sky", "data-arcmin-per-unit": 1 / k });
  root.append(chartLayer(root, tp.ra_deg, tp.dec_deg, halfArcmin, 0, half));
  const items = [], obstacles = [];
  result.pointings.forEach((p, i) => {
    root.append(svg("circle", { class: "pointing-fov", cx: centres[i][0], cy: centres[i][1], r, fill: "none",
      stroke: p.executable ? "#1f4e99" : "#c62828", "stroke-width": 0.4 * u,
      "data-kind": p.executable ? "fov-executable" : "fov-not-executable" }, svg("title", {}, `pointing ${p.id}`)));
    const [cx, cy] = centres[i], anchors = POINTING_LABEL_ANGLES.map((a) => [cx + r * Math.cos(a), cy - r * Math.sin(a)]);
    items.push({ id: p.id, x: anchors[0][0], y: anchors[0][1], anchors, r: 0, gap: 0.3 * u, text: p.id, fs: 4.5 * u,
      colour: p.executable ? "#1f4e99" : "#c62828", priority: Infinity, kind: "pointing-label" });
  });
  for (const s of request.sky_positions || []) {
    const [x, y] = sky(s.ra_deg, s.dec_deg);
    root.append(skyPositionMark(x, y, 1.6 * u, { class: "sky-position", "data-kind": "sky-position" },
      `sky position ${radecText(s.ra_deg, s.dec_deg)}`));
  }
  const targetItems = skyTargets(root, request, pts, tiers, fate, u, obstacles);
  const head = headerText(SKY_CONVENTION, -half + 2 * u, -half + 5 * u, 3.6 * u, "convention");
  const marks = [skyCompass(half, u), skyScale(half, u, k)];
  root.append(head, ...marks.map((m) => m.node));
  const all = [...items, ...targetItems];
  const headBoxes = measureTexts(root, ["field", "viewer"], all, [head]);
  const placed = placeLabels(all, [...obstacles, ...headBoxes, ...marks.map((m) => m.box)], [-half, -half, half, half]);
  const labels = labelNodes(placed, "labels");
  for (const t of labels.querySelectorAll("text")) {
    if (items.some((i) => i.id === t.dataset.for)) { t.classList.add("pointing-label"); t.dataset.kind = "pointing-label"; }
  }
  root.insertBefore(labels, head);
  underlay(root);
  decorateLocks(root);
  return el("div", { class: "field" }, el("h3", {}, `The field on the sky about ${radecText(tp.ra_deg, tp.dec_deg)}`),
    el("p", {}, `${SKY_CONVENTION}; circles: the fields of view of the ${plural(result.pointings.length, "pointing")} ` +
      "(red: not executable); filled: observed, crosses: not observed; colour: priority."),
    el("div", { class: "viewer" }, root, legend(root, tiers)), el("p", { class: "finding-note" }));
}

// Where on its circle a pointing's id may sit, first preferred: NE, NW, SE, SW, then N, S, E, W
// (radians, counter-clockwise from East on the page).
const POINTING_LABEL_ANGLES = [45, 135, 315, 225, 90, 270, 0, 180].map((d) => d * Math.PI / 180);

// The targets' markers on the sky (appended to root), their boxes in `obstacles`; returns
// their label items, highest priority first.
function skyTargets(root, request, pts, tiers, fate, u, obstacles) {
  const items = [];
  request.targets.forEach((t, i) => {
    const f = fate.get(t.id), st = f && f.configuration !== undefined ? "this" : "unallocated";
    const tier = tiers.index(t.priority), [x, y] = pts[i];
    root.append(targetMark({ x: 0, y: 0 }, st, TIER_COLOURS[tier],
      { class: "sky-target", transform: `translate(${x},${y}) scale(${0.7 * u})`, "data-id": t.id, "data-tier": tier,
        "data-cx": x, "data-cy": y, "data-r": 2.4 * u,
        "data-kind": st === "this" ? "sky-observed" : "sky-unobserved" },
      `${t.id} (priority ${priorityText(t.priority)}): ${st === "this" ? "observed" : "not observed"}`));
    obstacles.push(markerBox(x, y, 2.4 * u));
    items.push({ id: t.id, x, y, r: 2.4 * u, gap: 0.5 * u, text: t.id, fs: 2.8 * u, priority: t.priority });
  });
  return items.sort((a, b) => b.priority - a.priority);
}

// A sky position: a small plus.
function skyPositionMark(x, y, r, attrs, title) {
  const g = svg("g", attrs || {}, svg("path", { d: `M${x - r},${y}H${x + r}M${x},${y - r}V${y + r}`, stroke: "#00897b", "stroke-width": r / 3 }));
  if (title) g.append(svg("title", {}, title));
  return g;
}

function skyCompass(half, u) {
  const cx = -0.8 * half, cy = -0.68 * half, L = 0.12 * half;
  const [nx, ny] = skySvg(0, L), [ex, ey] = skySvg(L, 0);
  return { node: svg("g", { class: "compass" },
    svg("line", { x1: cx, y1: cy, x2: cx + nx, y2: cy + ny, stroke: "#000", "stroke-width": 0.4 * u, "data-dir": "N" }),
    svg("text", { x: cx + 1.3 * nx - 2 * u, y: cy + 1.3 * ny, "font-size": 6 * u }, "N"),
    svg("line", { x1: cx, y1: cy, x2: cx + ex, y2: cy + ey, stroke: "#000", "stroke-width": 0.4 * u, "data-dir": "E" }),
    svg("text", { x: cx + 1.3 * ex - 4 * u, y: cy + ey + 2 * u, "font-size": 6 * u }, "E")),
  box: [cx - 1.6 * L, cy - 1.6 * L, cx + 0.3 * L, cy + 0.3 * L] };
}

// A scale bar of a round number of arcmin (k: SVG units per arcmin).
function skyScale(half, u, k) {
  const arcmin = [60, 30, 20, 10, 5, 2, 1, 0.5, 0.2, 0.1].find((b) => b * k <= half / 2) || 0.1, bar = arcmin * k;
  return { node: svg("g", { class: "scale-bar" },
    svg("line", { class: "sky-scale", x1: 0.9 * half - bar, y1: 0.9 * half, x2: 0.9 * half, y2: 0.9 * half, stroke: "#000", "stroke-width": 0.6 * u }),
    svg("text", { x: 0.9 * half - bar, y: 0.9 * half - 2 * u, "font-size": 5 * u }, `${arcmin}′`)),
  box: [0.9 * half - bar - u, 0.9 * half - 7 * u, half, half] };
}
