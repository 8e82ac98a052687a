// MXS planner page: the label layout of the pictures (greedy, collision-avoiding).
// Loaded after viewer.js (whose svg and el helpers it uses) and before app.js.
"use strict";

// Measure label texts (and a picture's fixed texts) as the browser draws them: a picture not
// yet on the page goes for a moment into an off-screen host styled like its place there
// (`hostClasses`, outermost first), because text metrics depend on the drawn scale. Sets each
// item's size = [dx, dy, w, h] (its box from the baseline's left end); returns the fixed
// texts' boxes [x0, y0, x1, y1].
function measureTexts(root, hostClasses, items, fixedNodes) {
  const probe = svg("g", { class: "label-probe" });
  const nodes = items.map((it) => svg("text", { x: 0, y: 0, "font-size": it.fs, "font-family": LABEL_FONT }, it.text));
  probe.append(...nodes);
  root.append(probe);
  let host = null;
  if (!root.isConnected && document.body) {
    host = el("div", { style: "position:absolute;left:-10000px;top:0;width:80em;visibility:hidden" });
    let inner = host;
    for (const c of hostClasses) { const d = el("div", { class: c }); inner.append(d); inner = d; }
    inner.append(root);
    document.body.append(host);
  }
  items.forEach((it, i) => {
    const b = nodes[i].getBBox();
    it.size = b.width > 0 ? [b.x, b.y, b.width, b.height] : [0, -0.95 * it.fs, 0.62 * it.fs * it.text.length, 1.25 * it.fs];
  });
  const fixed = fixedNodes.map((t) => { const b = t.getBBox(); return [b.x, b.y, b.x + b.width, b.y + b.height]; });
  probe.remove();
  if (host) { root.remove(); host.remove(); }
  return fixed;
}

function boxesOverlap(a, b) { return a[0] < b[2] && b[0] < a[2] && a[1] < b[3] && b[1] < a[3]; }

// Where a label may go around a marker: the 8 directions next to it, then the same directions
// further out (drawn with a leader line).
const LABEL_DIRECTIONS = [[1, 0], [-1, 0], [0, -1], [0, 1], [1, -1], [-1, -1], [1, 1], [-1, 1]];

function candidateBoxes(item, w, h) {
  const out = [];
  for (const ring of [0, 1.6, 3.4]) {
    for (const [ax, ay] of item.anchors || [[item.x, item.y]]) {
      for (const [dx, dy] of LABEL_DIRECTIONS) {
        const d = item.r + item.gap + ring * h, n = Math.hypot(dx, dy);
        const px = ax + d * dx / n, py = ay + d * dy / n;
        const x0 = dx > 0 ? px : dx < 0 ? px - w : px - w / 2, y0 = dy > 0 ? py : dy < 0 ? py - h : py - h / 2;
        out.push({ box: [x0, y0, x0 + w, y0 + h], leader: ring > 0, ax, ay });
      }
    }
  }
  return out;
}

// Greedy collision-avoiding layout: items (in priority order: {x, y, r, gap, text, fs, size};
// optional `anchors`, the points it may sit beside, [[x, y], ...], first preferred) take
// the first candidate box that overlaps no obstacle (markers, fixed texts), no label already
// placed, and stays inside `bounds`; an item with no such box gets no label (its marker keeps
// the id as a tooltip). Returns [{item, box, x, y (baseline), leader: [x1, y1, x2, y2] | null}].
function placeLabels(items, obstacles, bounds) {
  const placed = [], taken = obstacles.slice();
  for (const item of items) {
    const [dx, dy, w, h] = item.size, pad = 0.05 * h;
    for (const c of candidateBoxes(item, w + 2 * pad, h + 2 * pad)) {
      const b = c.box;
      if (b[0] < bounds[0] || b[1] < bounds[1] || b[2] > bounds[2] || b[3] > bounds[3]) continue;
      if (taken.some((o) => boxesOverlap(b, o))) continue;
      taken.push(b);
      placed.push({ item, box: b, x: b[0] + pad - dx, y: b[1] + pad - dy, leader: c.leader ? leaderLine({ ...item, x: c.ax, y: c.ay }, b) : null });
      break;
    }
  }
  return placed;
}

// From the marker's edge to the nearest point of the label's box.
function leaderLine(item, b) {
  const nx = Math.min(Math.max(item.x, b[0]), b[2]), ny = Math.min(Math.max(item.y, b[1]), b[3]);
  const d = Math.hypot(nx - item.x, ny - item.y) || 1;
  return [item.x + item.r * (nx - item.x) / d, item.y + item.r * (ny - item.y) / d, nx, ny];
}

// SVG nodes of placed labels: the text (its estimated box in data-box, for checks) and leaders.
function labelNodes(placed, cls) {
  const g = svg("g", { class: cls });
  for (const pl of placed) {
    if (pl.leader) {
      const [x1, y1, x2, y2] = pl.leader;
      g.append(svg("line", { class: "leader", x1, y1, x2, y2, stroke: "#777", "stroke-width": pl.item.fs / 14 }));
    }
    g.append(svg("text", { class: "label", x: pl.x, y: pl.y, "font-size": pl.item.fs, "font-family": LABEL_FONT,
      fill: pl.item.colour || "#222", "data-for": pl.item.id, "data-box": pl.box.join(" ") }, pl.item.text));
  }
  return g;
}

// A marker's box as an obstacle for labels.
function markerBox(x, y, r) { return [x - r, y - r, x + r, y + r]; }

