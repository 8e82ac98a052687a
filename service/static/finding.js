// MXS planner page: the finding chart under the pictures (POST v1/finding-charts).
// Loaded after viewer.js (whose svg and el helpers it uses) and before app.js.
"use strict";

// The astronomer's FITS image (null: none) and the charts cut from it, by view.
const finding = { file: null, charts: new Map() };

// An empty layer under a picture, and the view a finding chart must cover: centre, half width
// (arcmin), up position angle (deg) and half width in SVG units (the chart spans the viewBox).
function chartLayer(root, raDeg, decDeg, halfArcmin, upPaDeg, half) {
  Object.assign(root.dataset, { chartRa: raDeg, chartDec: decDeg, chartHalfArcmin: halfArcmin, chartUpPa: upPaDeg, chartHalf: half });
  return svg("g", { class: "finding-chart" });
}

// POST v1/finding-charts for one view: a PNG whose up is the view's up and whose left is its left.
async function fetchChart(file, d) {
  const form = new FormData();
  form.append("image", file, file.name || "image.fits");
  const ra = ((Number(d.chartRa) % 360) + 360) % 360;
  for (const [k, v] of [["ra_deg", ra], ["dec_deg", d.chartDec], ["half_width_arcmin", d.chartHalfArcmin],
    ["up_pa_deg", d.chartUpPa], ["size_px", 512]]) form.append(k, String(v));
  const headers = typeof authHeaders === "function" ? authHeaders() : {};
  const r = await fetch("v1/finding-charts", { method: "POST", headers, body: form });
  if (!r.ok) {
    let body = null;
    try { body = await r.json(); } catch (e) { body = null; }
    const detail = body && (body.message || (typeof body.detail === "string" ? body.detail : null) ||
      (Array.isArray(body.detail) ? body.detail.map((e) => `${(e.loc || []).slice(-1)[0]}: ${e.msg}`).join("; ") : null));
    throw new Error(`finding chart: ${detail || "HTTP " + r.status}`);
  }
  return URL.createObjectURL(await r.blob());
}

// Draw the finding chart under one picture (fetched once per view); resolves to an error
// message or null.
async function underlay(root) {
  const layer = root.querySelector("g.finding-chart"), file = finding.file;
  if (!layer) return null;
  if (!file) { layer.replaceChildren(); return null; }
  const d = root.dataset, key = [d.chartRa, d.chartDec, d.chartHalfArcmin, d.chartUpPa].join("|");
  if (!finding.charts.has(key)) finding.charts.set(key, fetchChart(file, d));
  try {
    const url = await finding.charts.get(key);
    if (finding.file !== file) return null;
    const h = Number(d.chartHalf);
    layer.replaceChildren(svg("image", { href: url, x: -h, y: -h, width: 2 * h, height: 2 * h,
      preserveAspectRatio: "none", class: "finding-image" }));
    return null;
  } catch (e) {
    if (finding.file === file) layer.replaceChildren();
    return e.message;
  }
}

// Use `file` (a FITS image with a celestial WCS; null: none) as the finding chart under every
// picture, drawn now and later; resolves to the first error message, or null.
async function setFindingImage(file) {
  for (const p of finding.charts.values()) p.then((url) => URL.revokeObjectURL(url), () => null);
  finding.charts.clear();
  finding.file = file || null;
  const errors = (await Promise.all([...document.querySelectorAll("svg[data-chart-ra]")].map(underlay))).filter(Boolean);
  for (const n of document.querySelectorAll(".finding-note")) n.textContent = errors[0] || "";
  return errors[0] || null;
}

// The viewer's entry points for app.js and tests.
window.MXSViewer = { setFindingImage, placeLabels, fpSvg, skySvg };
