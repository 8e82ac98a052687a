// MXS planner page: how numbers, coordinates and counts are written. Loaded first; used by
// viewer.js and app.js.
"use strict";

// "1 pointing", "3 pointings" (plural given when it is not noun + "s").
function plural(n, noun, pluralNoun) {
  return `${n} ${n === 1 ? noun : (pluralNoun || noun + "s")}`;
}

// A value split into sexagesimal parts, rounded at `decimals` of the last part.
function sexagesimalParts(value, decimals) {
  const scale = 10 ** decimals;
  let total = Math.round(Math.abs(value) * 3600 * scale);
  const last = total % (60 * scale);
  total = (total - last) / (60 * scale);
  const mid = total % 60;
  const first = (total - mid) / 60;
  return [first, mid, last / scale];
}

function pad2(n) { return String(n).padStart(2, "0"); }

function padLast(v, decimals) {
  const s = v.toFixed(decimals);
  return (v < 10 ? "0" : "") + s;
}

// Right ascension in hours, minutes and seconds: "08h51m23.12s" (seconds to 0.01 s).
function raHms(raDeg) {
  const ra = ((raDeg % 360) + 360) % 360;
  const [h, m, s] = sexagesimalParts(ra / 15, 2);
  return `${pad2(h % 24)}h${pad2(m)}m${padLast(s, 2)}s`;
}

// Declination in degrees, minutes and seconds: "+11°48′00.1″" (seconds to 0.1″).
function decDms(decDeg) {
  const [d, m, s] = sexagesimalParts(decDeg, 1);
  const sign = decDeg < 0 && (d || m || s) ? "−" : "+";
  return `${sign}${pad2(d)}°${pad2(m)}′${padLast(s, 1)}″`;
}

// Both forms of a position: "08h51m23.12s +11°48′00.1″ (132.84633°, +11.80003°)".
function radecText(raDeg, decDeg) {
  const dec = `${decDeg >= 0 ? "+" : "−"}${Math.abs(decDeg).toFixed(5)}°`;
  return `${raHms(raDeg)} ${decDms(decDeg)} (${raDeg.toFixed(5)}°, ${dec})`;
}

// An integer priority as the user wrote it ("-5", not "-5.0").
function priorityText(p) {
  return Number.isInteger(p) ? String(p) : String(Number(p));
}
