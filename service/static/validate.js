// MXS planner page: "Check a plan file" (issue 39), for GTC staff handed a plan.json. The file
// is sent as it is to POST v1/validations, which re-verifies every configuration and trajectory
// with the independent verifier and checks the content hash; the answer is shown as valid, or
// as its violations. Loaded after viewer.js (el) and before app.js (authHeaders).
"use strict";

// The text of member `key` of the JSON object `text` (top level), as written; null if absent.
// The plan is downloaded as the server wrote it: a JavaScript writer turns 900.0 into 900, and
// the plan's content hash is over the numbers as the server wrote them.
function rawMember(text, key) {
  let depth = 0, i = 0, lastString = null, valueStart = -1;
  const want = JSON.stringify(key);
  while (i < text.length) {
    const ch = text[i];
    if (ch === '"') {
      let j = i + 1;
      while (text[j] !== '"') j += text[j] === "\\" ? 2 : 1;
      lastString = text.slice(i, j + 1);
      i = j + 1;
      continue;
    }
    if (ch === ":" && depth === 1 && lastString === want) {
      valueStart = i + 1;
    } else if (ch === "{" || ch === "[") {
      depth += 1;
    } else if (ch === "}" || ch === "]" || ch === ",") {
      if (valueStart >= 0 && depth === 1) return text.slice(valueStart, i).trim();
      if (ch !== ",") depth -= 1;
    }
    i += 1;
  }
  return null;
}

// Violations listed open; more are folded under a summary.
const VIOLATIONS_SHOWN = 20;

// Where a violation is: "pointing P0001, c2, leg 3, arm 4" (the parts it names; configurations
// and legs are counted from 1 by the server, leg 1: park -> c1).
function violationWhere(v) {
  const parts = [];
  if (v.pointing !== null && v.pointing !== undefined) parts.push(`pointing ${v.pointing}`);
  if (v.configuration !== null && v.configuration !== undefined) parts.push(`c${v.configuration}`);
  if (v.leg !== null && v.leg !== undefined) parts.push(`leg ${v.leg}`);
  if (v.arm !== null && v.arm !== undefined) parts.push(`arm ${v.arm}`);
  return parts.join(", ");
}

// The verdict on a plan file: valid, or each violation with where it is and its kind.
function showValidation(name, answer) {
  const box = document.getElementById("validation");
  const ok = answer.valid === true;
  box.className = "validation " + (ok ? "good" : "bad");
  const hash = answer.hash_ok === false ? "its content hash does NOT match its content (edited after planning)" :
    answer.hash_ok === true ? "its content hash matches" : "";
  const counts = Object.entries(answer.checked || {}).map(([k, v]) => `${v} ${k.replace(/_/g, " ")}`).join(", ");
  box.replaceChildren(el("p", { class: "verdict" }, ok ? `${name}: VALID` : `${name}: NOT VALID`,
    hash ? ` — ${hash}.` : "."), counts ? el("p", { class: "checked" }, `Checked: ${counts}.`) : null);
  const violations = answer.violations || [];
  if (violations.length) {
    const items = violations.map((v) => el("li", { "data-kind": v.kind },
      (violationWhere(v) ? `${violationWhere(v)}: ` : "") + `${v.kind}: ${v.message}`));
    const list = el("ul", { class: "violations" }, ...items.slice(0, VIOLATIONS_SHOWN));
    const total = Math.max(answer.violations_total || 0, violations.length);
    box.append(el("p", {}, `${plural(total, "violation")}` + (total > violations.length ? ` (the first ${violations.length})` : "") + ":"), list);
    if (items.length > VIOLATIONS_SHOWN) {
      box.append(el("details", {}, el("summary", {}, `${items.length - VIOLATIONS_SHOWN} more`),
        el("ul", { class: "violations" }, ...items.slice(VIOLATIONS_SHOWN))));
    }
  }
  box.hidden = false;
}

function showValidationError(text) {
  const box = document.getElementById("validation");
  box.className = "validation error";
  box.replaceChildren(el("p", {}, text));
  box.hidden = false;
}

// Read the chosen plan file and POST it, unchanged, to v1/validations.
async function checkPlanFile() {
  const file = document.getElementById("plan-file").files[0];
  const box = document.getElementById("validation");
  if (!file) { box.hidden = true; return; }
  box.className = "validation";
  box.replaceChildren(el("p", {}, `checking ${file.name} ...`));
  box.hidden = false;
  const text = await file.text();
  try { JSON.parse(text); } catch (e) { showValidationError(`${file.name}: not a JSON file (${e.message})`); return; }
  const headers = { "Content-Type": "application/json", ...(typeof authHeaders === "function" ? authHeaders() : {}) };
  const r = await fetch("v1/validations", { method: "POST", headers, body: text });
  let body = null;
  try { body = await r.json(); } catch (e) { body = null; }
  if (r.status === 200 && body) { showValidation(file.name, body); return; }
  const detail = body && (typeof body.message === "string" ? body.message : Array.isArray(body.detail) ?
    body.detail.map((d) => `${(d.loc || []).filter((p) => p !== "body").join(".")}: ${d.msg}`).join("\n") :
    typeof body.detail === "string" ? body.detail : null);
  showValidationError(`${file.name}: NOT checked: ${detail || "HTTP " + r.status}`);
}

function startValidation() {
  document.getElementById("plan-file").onchange = checkPlanFile;
  document.getElementById("plan-recheck").onclick = checkPlanFile;
}
