// MXS planner page: locks, exclusions and kept configurations (issue 39). A click (or Enter) on
// a target in the sky view or the configuration viewer, or on an arm in the viewer, opens a
// small menu: lock the target to the arm observing it (and its branch), to another arm, exclude
// it, or clear it. The list of locks and exclusions sits by the Plan button, each with a remove
// button; the next plan sends them as `locked`, `excluded_targets` and `keep_configurations`.
// Loaded after viewer.js and before form.js and app.js, whose state, el and svg it uses.
"use strict";

// target id -> {arm, branch}; excluded target ids; the configurations kept (null: none).
// `opener`: the marker or arm whose menu is open.
const locks = { locked: new Map(), excluded: new Set(), keep: null, opener: null };

// ------------------------------------------------------------------------ the request

// The request fields of the locks, exclusions and kept configurations; empty ones are left out.
function lockFields() {
  const out = {};
  if (locks.locked.size) {
    out.locked = [...locks.locked].map(([id, l]) => ({ target_id: id, arm: l.arm, branch: l.branch }));
  }
  if (locks.excluded.size) out.excluded_targets = [...locks.excluded];
  if (locks.keep) out.keep_configurations = locks.keep.kept;
  return out;
}

// The locks of a request (a plan restored after a reload).
function setLockState(values) {
  locks.locked = new Map((values.locked || []).map((l) => [l.target_id, { arm: l.arm, branch: l.branch ?? null }]));
  locks.excluded = new Set(values.excluded_targets || []);
  const kept = values.keep_configurations;
  locks.keep = kept ? { k: Math.max(1, ...kept.pointings.map((p) => p.configurations.length)), kept } : null;
  renderLocks();
}

// `--keep` of the command line: the plan shown, downloaded as plan.json, and k.
function keepFlag() { return `plan.json:${locks.keep ? locks.keep.k : 1}`; }

// Configurations c1..ck of every pointing of a plan with configurations, as
// `keep_configurations` takes them: the pointing (id, centre, PA, members) and each kept
// configuration's 12 arm states (arm, target or null, joint angles) as the plan gave them.
function keptConfigurations(result, k) {
  return { pointings: result.pointings.filter((p) => p.configurations.length).map((p) => ({
    id: p.id, ra_deg: p.ra_deg, dec_deg: p.dec_deg, position_angle_deg: p.position_angle_deg ?? null,
    target_ids: p.target_ids,
    configurations: p.configurations.slice(0, k).map((c) => c.assignments.map((a) => ({
      arm: a.arm, target_id: a.target_id ?? null, theta1_rad: a.theta1_rad, theta2_rad: a.theta2_rad }))),
  })) };
}

// ------------------------------------------------------------------------ changes

function changed() {
  renderLocks();
  redecorate();
  if (typeof markStale === "function") markStale();
}

function lockTarget(id, arm, branch) {
  locks.excluded.delete(id);
  locks.locked.set(id, { arm, branch: branch ?? null });
  changed();
}

function excludeTarget(id) {
  locks.locked.delete(id);
  locks.excluded.add(id);
  changed();
}

function clearTarget(id) {
  locks.locked.delete(id);
  locks.excluded.delete(id);
  changed();
}

// Keep c1..ck of the plan shown (k from the form) and plan the rest.
function keepAndPlan() {
  if (!state.result) return;
  const k = Math.max(1, Math.floor(Number(document.getElementById("keep-k").value) || 1));
  locks.keep = { k, kept: keptConfigurations(state.result, k) };
  changed();
  document.getElementById("go").click();
}

// ------------------------------------------------------------------------ the list

function renderLocks() {
  const list = document.getElementById("lock-list");
  const items = [];
  const remove = (label, fn) => el("button", { type: "button", class: "remove", "aria-label": `remove: ${label}`, onclick: fn }, "remove");
  for (const [id, l] of locks.locked) {
    const text = `${id} locked to arm ${l.arm}` + (l.branch === null ? "" : `, branch ${l.branch}`);
    items.push(el("li", { "data-lock": id }, text + " ", remove(text, () => clearTarget(id))));
  }
  for (const id of locks.excluded) {
    items.push(el("li", { "data-exclude": id }, `${id} excluded `, remove(`${id} excluded`, () => clearTarget(id))));
  }
  if (locks.keep) {
    const text = `keep c1..c${locks.keep.k} of ${plural(locks.keep.kept.pointings.length, "pointing")} as planned`;
    items.push(el("li", { "data-keep": locks.keep.k }, text + " ", remove(text, () => { locks.keep = null; changed(); })));
  }
  list.replaceChildren(...items);
  document.getElementById("locks-none").hidden = items.length > 0;
  document.getElementById("keep-go").disabled = !state.result;
}

// The target ids of the table read last, offered by the lock form.
function offerTargetIds(targets) {
  document.getElementById("target-ids").replaceChildren(...targets.map((t) => el("option", { value: t.id })));
}

// The lock form: a target typed or chosen, locked to the arm chosen or excluded.
function lockFromForm(exclude) {
  const id = document.getElementById("lock-target").value.trim();
  if (!id) { document.getElementById("lock-target").focus(); return; }
  if (exclude) excludeTarget(id);
  else lockTarget(id, Number(document.getElementById("lock-arm").value), null);
}

// ------------------------------------------------------------------------ the menu

// What a clicked node of a picture names: {target, arm, branch, where} (arm null: the target
// is not observed) or null.
function pickedInPicture(node) {
  const conf = node.closest("svg.configuration"), sky = node.closest("svg.sky");
  if (!state.result || (!conf && !sky)) return null;
  const marker = node.closest("[data-id]"), armNode = conf && node.closest("g.arm");
  if (sky) return marker ? observedBy(marker.dataset.id, null, null) : null;
  const p = state.result.pointings.find((q) => q.id === conf.closest(".pointing").dataset.pointing);
  const k = Number(conf.dataset.configuration) - 1;
  if (marker) return observedBy(marker.dataset.id, p, k);
  if (!armNode) return null;
  const a = p.configurations[k].assignments.find((x) => x.arm === Number(armNode.dataset.arm));
  return a && a.target_id ? { target: a.target_id, arm: a.arm, branch: a.branch ?? null, where: `c${k + 1}` } :
    { target: null, arm: Number(armNode.dataset.arm), branch: null, where: `c${k + 1}` };
}

// The arm observing a target: in configuration k of pointing p when it is observed there, else
// in the first configuration of the plan that observes it.
function observedBy(id, p, k) {
  const found = [];
  for (const q of state.result.pointings) {
    q.configurations.forEach((c, j) => {
      const a = c.assignments.find((x) => x.target_id === id);
      if (a) found.push({ target: id, arm: a.arm, branch: a.branch ?? null, where: `${q.id} c${j + 1}`, here: q === p && j === k });
    });
  }
  return found.find((f) => f.here) || found[0] || { target: id, arm: null, branch: null, where: null };
}

// Close the menu; `refocus`: give the focus back to the marker or arm that opened it (Escape).
function closeMenu(refocus) {
  const m = document.getElementById("lock-menu");
  if (!m) return;
  m.remove();
  if (refocus && locks.opener && locks.opener.isConnected) locks.opener.focus();
}

// The menu for a picked target or arm, at page position (x, y); its first button has focus.
function openMenu(picked, x, y, opener) {
  closeMenu();
  locks.opener = opener;
  const act = (fn) => () => { closeMenu(); fn(); };
  const menu = el("div", { id: "lock-menu", class: "lock-menu", role: "dialog", "aria-label": "lock or exclude",
    style: `left:${x}px;top:${y}px` });
  const id = picked.target;
  if (!id) {
    menu.append(el("p", {}, `arm ${picked.arm} observes no target in ${picked.where}`));
  } else {
    menu.append(el("p", {}, `${id}: ` + (picked.arm === null ? "not observed" : `arm ${picked.arm} in ${picked.where}`)));
    if (picked.arm !== null) {
      const b = picked.branch === null ? "" : `, branch ${picked.branch}`;
      menu.append(el("button", { type: "button", class: "lock-here", onclick: act(() => lockTarget(id, picked.arm, picked.branch)) },
        `lock to arm ${picked.arm}${b}`));
    }
    const arm = el("select", { class: "lock-arm", "aria-label": "arm" },
      ...[...Array(12).keys()].map((a) => el("option", { value: a }, `arm ${a}`)));
    menu.append(el("span", { class: "lock-other" }, "or to ", arm, " ",
      el("button", { type: "button", class: "lock-to", onclick: act(() => lockTarget(id, Number(arm.value), null)) }, "lock")),
    el("button", { type: "button", class: "exclude", onclick: act(() => excludeTarget(id)) }, "exclude"),
    el("button", { type: "button", class: "clear", onclick: act(() => clearTarget(id)) }, "clear"));
  }
  menu.append(el("button", { type: "button", class: "close", onclick: () => closeMenu(true) }, "close"));
  menu.addEventListener("keydown", (e) => { if (e.key === "Escape") closeMenu(true); });
  document.body.append(menu);
  menu.querySelector("button").focus();
}

// Clicks and Enter/Space on the pictures open the menu; a click elsewhere closes it.
function onPictureEvent(e) {
  if (e.type === "keydown" && e.key !== "Enter" && e.key !== " ") return;
  if (e.target.closest && e.target.closest("#lock-menu")) return;
  const picked = e.target.closest ? pickedInPicture(e.target) : null;
  if (!picked) { if (e.type === "click") closeMenu(); return; }
  e.preventDefault();
  const r = e.target.getBoundingClientRect();
  const x = e.type === "click" ? e.pageX : r.right + window.scrollX, y = e.type === "click" ? e.pageY : r.bottom + window.scrollY;
  openMenu(picked, x + 4, y + 4, e.target.closest("[tabindex]"));
}

// ------------------------------------------------------------------------ marks in the pictures

const LOCK_KINDS = { "mark-locked": ["#1b5e20", "locked to an arm (the next plan keeps it there)"],
  "mark-excluded": ["#c62828", "excluded (never observed by the next plan)"] };

// A ring (locked) or a crossed ring (excluded) of radius r about (x, y).
function lockMark(kind, x, y, r, extra) {
  const c = LOCK_KINDS[kind][0], w = r / 5;
  const g = svg("g", { class: "lock-mark", "data-kind": kind, "pointer-events": "none", ...extra },
    svg("circle", { cx: x, cy: y, r, fill: "none", stroke: c, "stroke-width": w }));
  if (kind === "mark-excluded") {
    const d = r * Math.SQRT1_2;
    g.append(svg("line", { x1: x - d, y1: y - d, x2: x + d, y2: y + d, stroke: c, "stroke-width": w }));
  }
  return g;
}

function lockSwatch(kind) {
  const s = svg("svg", { viewBox: "-5 -5 10 10" });
  s.append(lockMark(kind, 0, 0, 3.8));
  return s;
}

// Mark the locked and excluded targets of a picture, and make its targets and arms reachable
// by keyboard (Tab, then Enter opens the menu).
function decorateLocks(root) {
  for (const old of root.querySelectorAll("g.lock-mark")) old.remove();
  const marks = svg("g", { class: "lock-marks" });
  for (const m of root.querySelectorAll("[data-id][data-cx]")) {
    m.setAttribute("tabindex", "0");
    m.setAttribute("role", "button");
    const id = m.dataset.id, kind = locks.locked.has(id) ? "mark-locked" : locks.excluded.has(id) ? "mark-excluded" : null;
    if (kind) marks.append(lockMark(kind, +m.dataset.cx, +m.dataset.cy, 1.7 * +m.dataset.r, { "data-for": id }));
  }
  for (const a of root.querySelectorAll("g.arm")) { a.setAttribute("tabindex", "0"); a.setAttribute("role", "button"); }
  const old = root.querySelector("g.lock-marks");
  if (old) old.replaceWith(marks); else root.append(marks);
  return root;
}

// After a change: the marks of every picture shown, and their legends' entries.
function redecorate() {
  for (const root of document.querySelectorAll("svg.configuration, svg.sky")) {
    decorateLocks(root);
    const legendList = root.parentElement && root.parentElement.querySelector("ul.legend");
    if (!legendList) continue;
    for (const li of legendList.querySelectorAll("li[data-kind^='mark-']")) li.remove();
    const kinds = new Set([...root.querySelectorAll("g.lock-mark")].map((n) => n.dataset.kind));
    const note = legendList.querySelector("li.note");
    for (const k of Object.keys(LOCK_KINDS)) {
      if (kinds.has(k)) legendList.insertBefore(el("li", { "data-kind": k }, lockSwatch(k), " " + LOCK_KINDS[k][1]), note);
    }
  }
}

function startLocks() {
  document.addEventListener("click", onPictureEvent);
  document.addEventListener("keydown", onPictureEvent);
  document.getElementById("lock-add").onclick = () => lockFromForm(false);
  document.getElementById("exclude-add").onclick = () => lockFromForm(true);
  document.getElementById("keep-go").onclick = keepAndPlan;
  renderLocks();
}
