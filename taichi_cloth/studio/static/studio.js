// The pattern studio's page: draws the state the server sends (GET /api/state) and sends each edit to its route;
// every edit's answer carries the whole new state. Plain DOM and SVG, no libraries (the page works offline).
"use strict";

const SEAM_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
                      "#bcbd22", "#17becf"];  // matplotlib's tab10, as in the seam set-up picture
const SVGNS = "http://www.w3.org/2000/svg";
const $ = (id) => document.getElementById(id);

let state = null;          // the last state from the server
let pick = null;           // a seam being picked: {a: side or null, spanStart: {piece, corner} or null}
let selectedSeam = null;   // index
let selectedPiece = null;  // name
let drapePoll = null;
let placementShown = -1;   // the version the placement picture shows
let formsShown = {};       // what each form was last filled from: a redraw refills a form only when that changed,
                           // so an answer arriving while the user types does not wipe what is typed

// ------------------------------------------------------------------------------------------------ server calls
async function api(method, url, body) {
  const options = {method, headers: {}};
  if (body instanceof FormData) options.body = body;
  else if (body !== undefined) {
    options.headers["Content-Type"] = "application/json";
    options.body = JSON.stringify(body);
  }
  let response, data;
  try {
    response = await fetch(url, options);
  } catch (err) {
    say(`the studio does not answer (${err.message}); is it still running?`, "error");
    return null;
  }
  const text = await response.text();
  try { data = JSON.parse(text); } catch (err) { data = {error: text || response.statusText}; }
  if (!response.ok) {
    data.status = response.status;
    say(data.error || `${response.status} ${response.statusText}`, "error");
    return data;
  }
  if (data.state) render(data.state);
  return data;
}

function say(text, kind) {
  const m = $("message");
  m.textContent = text || "";
  m.className = text ? kind : "";
}

// ------------------------------------------------------------------------------------------------ drawing
function el(name, attrs, parent) {
  const e = document.createElementNS(SVGNS, name);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (parent) parent.appendChild(e);
  return e;
}

function pathOf(points) {
  return points.map((p, i) => `${i ? "L" : "M"}${p[0]},${-p[1]}`).join(" ");
}

function midpoint(points) {
  // the point half way along a polyline and the unit tangent there
  let total = 0;
  const len = [];
  for (let i = 1; i < points.length; i++) {
    const d = Math.hypot(points[i][0] - points[i - 1][0], points[i][1] - points[i - 1][1]);
    len.push(d); total += d;
  }
  let run = 0;
  for (let i = 1; i < points.length; i++) {
    if (run + len[i - 1] >= total / 2 || i === points.length - 1) {
      const t = len[i - 1] > 0 ? (total / 2 - run) / len[i - 1] : 0;
      const a = points[i - 1], b = points[i];
      const dx = (b[0] - a[0]) / (len[i - 1] || 1), dy = (b[1] - a[1]) / (len[i - 1] || 1);
      return {x: a[0] + t * (b[0] - a[0]), y: a[1] + t * (b[1] - a[1]), tx: dx, ty: dy};
    }
    run += len[i - 1];
  }
  return {x: points[0][0], y: points[0][1], tx: 1, ty: 0};
}

function drawPattern() {
  const svg = $("pattern");
  svg.textContent = "";
  if (!state || !state.open) return;
  const all = state.pieces.flatMap((p) => p.outline);
  const xs = all.map((p) => p[0]), ys = all.map((p) => p[1]);
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const extent = Math.max(x1 - x0, y1 - y0);
  const u = extent / 200;  // the drawing's unit for strokes and text
  const pad = 16 * u;  // room for the corner names outside the outlines
  svg.setAttribute("viewBox", `${x0 - pad} ${-y1 - pad} ${x1 - x0 + 2 * pad} ${y1 - y0 + 2 * pad}`);
  const units = state.units;
  for (const piece of state.pieces) {
    const g = el("g", {class: "piece" + (piece.name === selectedPiece ? " selected" : ""), "data-piece": piece.name},
                 svg);
    const fill = el("path", {class: "piece-fill", d: pathOf(piece.outline) + " Z", fill: piece.colour}, g);
    fill.addEventListener("click", () => selectPiece(piece.name));
    // the grain: v (up) and u (across) from the middle of the piece
    const [gx, gy] = piece.grain.at, s = piece.grain.size;
    el("path", {class: "grain", d: `M${gx},${-gy} L${gx},${-(gy + s)}`, "stroke-width": 0.35 * u}, g);
    el("path", {class: "grain", d: `M${gx},${-(gy + s) - 1.6 * u} l${-0.9 * u},${2 * u} l${1.8 * u},0 Z`}, g);
    el("path", {class: "grain", d: `M${gx},${-gy} L${gx + 0.6 * s},${-gy}`, "stroke-width": 0.35 * u}, g);
    el("path", {class: "grain", d: `M${gx + 0.6 * s + 1.6 * u},${-gy} l${-2 * u},${-0.9 * u} l0,${1.8 * u} Z`}, g);
    text(g, gx + 1.2 * u, -(gy + s) + 1.5 * u, "v grain", 2.2 * u, "#555", "start");
    text(g, gx + 0.6 * s, -gy + 3.2 * u, "u", 2.2 * u, "#555", "middle");
    const bottom = Math.min(...piece.outline.map((q) => q[1]));
    text(g, gx, -bottom + 9 * u, piece.name, 3.4 * u, "#333", "middle", "italic");
    for (const side of piece.sides) {
      const hit = el("path", {class: "side-hit", d: pathOf(side.points), "stroke-width": 2.6 * u,
                              "data-piece": piece.name, "data-side": side.index, "data-from": side.from,
                              "data-to": side.to}, g);
      el("path", {class: "side-line", d: pathOf(side.points), "stroke-width": 0.3 * u}, g);
      hit.addEventListener("click", (ev) => clickSide(ev, piece, side));
      const m = midpoint(side.points);
      const cx = piece.grain.at[0], cy = piece.grain.at[1];
      let nx = -m.ty, ny = m.tx;  // put the length outside the piece
      if ((m.x - cx) * nx + (m.y - cy) * ny < 0) { nx = -nx; ny = -ny; }
      text(g, m.x + 2.8 * u * nx, -(m.y + 2.8 * u * ny) + 0.8 * u, `${side.length.toFixed(1)}`, 2.2 * u, "#666",
           "middle");
    }
    for (const c of piece.corners) {
      const dot = el("circle", {class: "corner", cx: c.at[0], cy: -c.at[1], r: 0.9 * u, "data-piece": piece.name,
                                "data-corner": c.name}, g);
      if (pick && pick.spanStart && pick.spanStart.piece === piece.name && pick.spanStart.corner === c.name)
        dot.classList.add("span-start");
      dot.addEventListener("click", (ev) => { ev.stopPropagation(); clickCorner(piece, c.name); });
      let dx = c.at[0] - piece.grain.at[0], dy = c.at[1] - piece.grain.at[1];
      const d = Math.hypot(dx, dy) || 1;
      text(g, c.at[0] + 3.6 * u * dx / d, -(c.at[1] + 3.6 * u * dy / d) + 0.8 * u, c.name, 2.4 * u, "#111",
           "middle");
    }
  }
  // the seams: each side in its seam's colour, an arrow along the pick direction and the seam's number
  state.seams.forEach((seam, i) => {
    const colour = SEAM_COLOURS[(seam.number - 1) % SEAM_COLOURS.length];
    for (const key of ["a", "b"]) {
      const side = seam[key];
      const p = el("path", {class: "seam-side" + (i === selectedSeam ? " selected" : ""), d: pathOf(side.points),
                            stroke: colour, "stroke-width": (i === selectedSeam ? 1.6 : 1.0) * u,
                            "stroke-opacity": i === selectedSeam ? 1 : 0.85, "data-seam": i, "data-side": key},
                   svg);
      p.addEventListener("click", () => selectSeam(i));
      const m = midpoint(side.points);
      const ax = m.x + 2 * u * m.tx, ay = m.y + 2 * u * m.ty, bx = m.x - 2 * u * m.tx, by = m.y - 2 * u * m.ty;
      el("path", {d: `M${ax},${-ay} L${bx - 1.3 * u * m.ty},${-(by + 1.3 * u * m.tx)} ` +
                     `L${bx + 1.3 * u * m.ty},${-(by - 1.3 * u * m.tx)} Z`, fill: colour, "pointer-events": "none"},
         svg);
      const cx = state.pieces.find((q) => q.name === side.piece).grain.at;
      let nx = -m.ty, ny = m.tx;
      if ((m.x - cx[0]) * nx + (m.y - cx[1]) * ny > 0) { nx = -nx; ny = -ny; }  // the number inside the piece
      text(svg, m.x + 4 * u * nx, -(m.y + 4 * u * ny) + 1 * u, String(seam.number), 2.8 * u, colour, "middle",
           "normal", "700");
    }
  });
  if (pick && pick.a) {
    const piece = state.pieces.find((q) => q.name === pick.a.piece);
    if (piece) el("path", {class: "picked-side", d: pathOf(sidePoints(piece, pick.a)), "stroke-width": 1.4 * u},
                  svg);
  }
}

function text(parent, x, y, content, size, fill, anchor, style, weight) {
  const t = el("text", {x, y, "font-size": size, fill, "text-anchor": anchor || "start",
                        "font-style": style || "normal", "font-weight": weight || "normal"}, parent);
  t.textContent = content;
  return t;
}

function sidePoints(piece, side) {
  // the outline between two corners, the shorter way round (as the seam planner takes it), for the pick highlight
  const names = piece.corners.map((c) => c.name);
  const n = names.length, i = names.indexOf(side.from), j = names.indexOf(side.to);
  const ahead = ((j - i) % n + n) % n;
  const first = 2 * ahead < n ? i : j, count = 2 * ahead < n ? ahead : n - ahead;
  let pts = [];
  for (let k = 0; k < count; k++) pts = pts.concat(piece.sides[(first + k) % n].points);
  return pts;
}

// ------------------------------------------------------------------------------------------------ seams
function pickHelp() {
  const h = $("pick-help");
  if (!pick) { h.textContent = "Click a side to start a seam."; h.className = ""; return; }
  h.className = "picking";
  const what = pick.a ? `side a: ${pick.a.piece} ${pick.a.from} → ${pick.a.to}. Now click the partner side`
                      : "Click the first side";
  h.textContent = what + (pick.spanStart ? ` (span from ${pick.spanStart.piece} ${pick.spanStart.corner}: ` +
                                           "click its end corner)" : "") + ". Esc cancels.";
}

function clickSide(ev, piece, side) {
  // the side runs from the corner nearer to the click
  const svg = $("pattern");
  const pt = svg.createSVGPoint();
  pt.x = ev.clientX; pt.y = ev.clientY;
  const q = pt.matrixTransform(svg.getScreenCTM().inverse());
  const first = side.points[0], last = side.points[side.points.length - 1];
  const dFirst = Math.hypot(q.x - first[0], -q.y - first[1]), dLast = Math.hypot(q.x - last[0], -q.y - last[1]);
  const picked = dFirst <= dLast ? {piece: piece.name, from: side.from, to: side.to}
                                 : {piece: piece.name, from: side.to, to: side.from};
  sidePicked(picked);
}

function clickCorner(piece, corner) {
  pick = pick || {a: null, spanStart: null};
  if (pick.spanStart && pick.spanStart.piece === piece.name && pick.spanStart.corner !== corner) {
    const start = pick.spanStart.corner;
    pick.spanStart = null;
    sidePicked({piece: piece.name, from: start, to: corner});
    return;
  }
  pick.spanStart = {piece: piece.name, corner};
  pickHelp();
  drawPattern();
}

async function sidePicked(side) {
  pick = pick || {a: null, spanStart: null};
  pick.spanStart = null;
  if (!pick.a) {
    pick.a = side;
    pickHelp();
    drawPattern();
    return;
  }
  const a = pick.a;
  pick = null;
  const r = await api("POST", "/api/seams", {a, b: side});
  if (r && r.state) {
    selectedSeam = r.index;
    const seam = r.state.seams[r.index];
    say(seam.pairs ? `seam ${seam.number} added` :
        `seam ${seam.number} added, but its sides are ${seam.a.length.toFixed(1)} and ${seam.b.length.toFixed(1)} ` +
        `${state.units} long: ${(100 * seam.mismatch).toFixed(1)} % apart, more than its tolerance`,
        seam.pairs ? "info" : "error");
    render(r.state);
  } else {
    pickHelp();
    drawPattern();
  }
}

function selectSeam(i) {
  selectedSeam = i;
  drawPattern();
  drawSeamList();
}

function drawSeamList() {
  const list = $("seam-list");
  list.textContent = "";
  if (!state || !state.open) return;
  state.seams.forEach((seam, i) => {
    const li = document.createElement("li");
    li.className = (i === selectedSeam ? "selected " : "") + (seam.pairs ? "" : "mismatch");
    li.dataset.seam = i;
    const colour = SEAM_COLOURS[(seam.number - 1) % SEAM_COLOURS.length];
    const side = (s) => `${s.piece} ${s.from} → ${s.to} (${s.length.toFixed(1)} ${state.units})`;
    li.innerHTML = `<span class="swatch" style="background:${colour}">${seam.number}</span>` +
      `<input class="seam-name"> <button class="flip-a" title="reverse side a">flip a</button> ` +
      `<button class="flip-b" title="reverse side b">flip b</button> <button class="delete">delete</button> ` +
      `<label class="tol" title="the largest length difference of the sides it sews">± <input class="seam-tol" ` +
      `type="number" min="0" step="1"> %</label><span class="sides"></span>`;
    li.querySelector(".seam-name").value = seam.name;
    li.querySelector(".seam-tol").value = +(100 * seam.tolerance).toFixed(3);
    li.querySelector(".seam-tol").addEventListener("change", (ev) =>
      api("PATCH", `/api/seams/${i}`, {tolerance: Number(ev.target.value) / 100}));
    li.querySelector(".sides").textContent = `a: ${side(seam.a)} · b: ${side(seam.b)}`;
    if (!seam.pairs) {
      const w = document.createElement("span");
      w.className = "mismatch-text sides";
      w.textContent = `lengths ${seam.a.length.toFixed(1)} and ${seam.b.length.toFixed(1)} ${state.units}: ` +
        `${(100 * seam.mismatch).toFixed(1)} % apart (tolerance ${(100 * seam.tolerance).toFixed(0)} %)`;
      li.appendChild(w);
    }
    li.addEventListener("click", (ev) => { if (ev.target.tagName !== "BUTTON") selectSeam(i); });
    li.querySelector(".seam-name").addEventListener("change", (ev) =>
      api("PATCH", `/api/seams/${i}`, {name: ev.target.value}));
    li.querySelector(".flip-a").addEventListener("click", () => api("POST", `/api/seams/${i}/flip`, {side: "a"}));
    li.querySelector(".flip-b").addEventListener("click", () => api("POST", `/api/seams/${i}/flip`, {side: "b"}));
    li.querySelector(".delete").addEventListener("click", () => {
      if (selectedSeam === i) selectedSeam = null;
      api("DELETE", `/api/seams/${i}`);
    });
    list.appendChild(li);
  });
  const w = $("warnings");
  w.textContent = "";
  for (const line of state.warnings || []) {
    const d = document.createElement("div");
    d.textContent = line;
    w.appendChild(d);
  }
}

// ------------------------------------------------------------------------------------------------ placement
function selectPiece(name) {
  selectedPiece = name;
  $("pl-piece").value = name;
  fillPlacement(true);
  drawPattern();
}

function changed(form, from, force) {
  // whether `form` must be refilled: forced, or what it shows changed on the server
  const key = JSON.stringify(from);
  if (!force && formsShown[form] === key) return false;
  formsShown[form] = key;
  return true;
}

function fillPlacement(force) {
  const name = $("pl-piece").value;
  const pl = (state.placements || {})[name] || {};
  const po = (state.pattern_options || {})[name] || {};
  const dx = state.dxf_options || {};
  if (!changed("placement", [name, pl, po, dx, state.dxf], force)) return;
  $("pl-anchor").value = pl.anchor || "";
  $("pl-at-u").value = pl.at ? pl.at[0] : "";
  $("pl-at-v").value = pl.at ? pl.at[1] : "";
  $("pl-offset").value = pl.offset !== undefined ? pl.offset : "";
  $("pl-height").value = pl.height !== undefined ? pl.height : "";
  $("pl-angle").value = pl.angle !== undefined ? pl.angle : "";
  $("pl-wrap").checked = pl.wrap !== false;
  $("pp-rotate").value = po.rotate !== undefined ? po.rotate : "";
  $("pp-allowance").value = po.seam_allowance !== undefined ? po.seam_allowance : "";
  $("pp-unfold").checked = po.unfold !== false;
  $("dxf-units").value = dx.dxf_units || "";
  $("dxf-size").value = dx.dxf_size || "";
  $("dxf-allowance").value = dx.seam_allowance !== undefined ? dx.seam_allowance : "";
  for (const id of ["pattern-options", "pp-apply", "dxf-options", "dxf-apply"]) $(id).hidden = !state.dxf;
}

async function applyPiecePattern() {
  const name = $("pl-piece").value;
  const body = {rotate: num("pp-rotate"), seam_allowance: num("pp-allowance"), unfold: $("pp-unfold").checked};
  const r = await api("PUT", `/api/pieces/${encodeURIComponent(name)}/pattern`, body);
  if (r && r.state) say(`${name}: pattern options set`, "info");
}

async function applyDxfOptions() {
  const body = {dxf_units: $("dxf-units").value || null, dxf_size: $("dxf-size").value.trim() || null,
                seam_allowance: num("dxf-allowance")};
  const r = await api("PUT", "/api/dxf", body);
  if (r && r.state) say("DXF options set", "info");
}

function num(id) {
  const v = $(id).value.trim();
  return v === "" ? null : Number(v);
}

async function applyPlacement() {
  const name = $("pl-piece").value;
  const body = {anchor: $("pl-anchor").value, offset: num("pl-offset"), height: num("pl-height"),
                angle: num("pl-angle"), wrap: $("pl-wrap").checked};
  const u = num("pl-at-u"), v = num("pl-at-v");
  if ((u === null) !== (v === null)) { say("give both at u and at v, or neither (the middle of the piece)", "error"); return; }
  if (u !== null) body.at = [u, v];
  const r = await api("PUT", `/api/placements/${encodeURIComponent(name)}`, body);
  if (r && r.state) say(`${name} placed at ${body.anchor}`, "info");
}

function drawPlacementTable() {
  const t = $("pl-table");
  t.textContent = "";
  if (!state || !state.open) return;
  t.innerHTML = "<tr><th>piece</th><th>anchor</th><th>at</th><th>offset</th><th>height</th></tr>";
  for (const piece of state.pieces) {
    const pl = state.placements[piece.name] || {};
    const tr = document.createElement("tr");
    const cells = [piece.name, pl.anchor || (pl.origin ? "free" : ""), pl.at ? `${pl.at[0]}, ${pl.at[1]}` : "middle",
                   pl.offset !== undefined ? pl.offset : "2 cm", pl.height || 0];
    for (const c of cells) { const td = document.createElement("td"); td.textContent = c; tr.appendChild(td); }
    tr.firstChild.style.borderLeft = `6px solid ${piece.colour}`;
    tr.addEventListener("click", () => selectPiece(piece.name));
    t.appendChild(tr);
  }
}

async function loadPlacementPicture() {
  if (!state || !state.open || placementShown === state.version) return;
  const version = state.version;
  $("pl-status").textContent = "drawing the placement…";
  const response = await fetch(`/api/views/placement.png?v=${version}`);
  if (!response.ok) {
    let msg = response.statusText;
    try { msg = (await response.json()).error; } catch (err) { /* keep the status text */ }
    $("pl-status").textContent = "";
    say(msg, "error");
    return;
  }
  const blob = await response.blob();
  const img = $("placement-img");
  if (img.dataset.url) URL.revokeObjectURL(img.dataset.url);
  img.dataset.url = URL.createObjectURL(blob);
  img.src = img.dataset.url;
  img.dataset.version = version;
  placementShown = version;
  $("pl-status").textContent = `front and side, set-up version ${version}`;
}

// ------------------------------------------------------------------------------------------------ material
function drawMaterial() {
  const m = state.material;
  const preset = $("mat-preset");
  if (!preset.options.length) {
    for (const name of Object.keys(state.presets)) preset.add(new Option(name, name));
    preset.addEventListener("change", () => fillMaterial(state.presets[preset.value]));
  }
  if (changed("material", m)) {
    preset.value = m.preset;
    fillMaterial(m.values);
  }
  if (changed("spacing", state.spacing)) $("spacing").value = state.spacing;
  $("particles").textContent = `about ${state.particles.toLocaleString("en")} particles at this spacing ` +
    `(estimate: the pieces' area / spacing² + their outlines / spacing)`;
}

const MATERIAL_UNITS = {density: "kg/m²", stretch: "N/m", shear: "N/m", bend: "N m", damping: "s",
                        viscosity: "m²/s"};

function fillMaterial(values) {
  const box = $("mat-values");
  if (!box.children.length) {
    for (const [k, unit] of Object.entries(MATERIAL_UNITS)) {
      const label = document.createElement("label");
      label.textContent = `${k} [${unit}]`;
      const input = document.createElement("input");
      input.type = "number"; input.step = "any"; input.min = "0"; input.id = `mat-${k}`;
      label.appendChild(input);
      box.appendChild(label);
    }
  }
  for (const k of Object.keys(MATERIAL_UNITS)) $(`mat-${k}`).value = values[k];
}

// ------------------------------------------------------------------------------------------------ drape
async function startDrape() {
  const body = {frames: Number($("drape-frames").value), quick: $("drape-quick").checked};
  if (body.quick && $("drape-spacing").value.trim() !== "") body.spacing = Number($("drape-spacing").value);
  const r = await api("POST", "/api/drape", body);
  if (r && r.state) { drawDrape(r.state.drape); watchDrape(); }
}

function watchDrape() {
  if (drapePoll) return;
  drapePoll = setInterval(async () => {
    const response = await fetch("/api/drape").catch(() => null);
    if (!response) return;
    const status = await response.json();
    drawDrape(status);
    if (status.state !== "running") { clearInterval(drapePoll); drapePoll = null; }
  }, 700);
}

function drawDrape(d) {
  const s = $("drape-status");
  $("drape-stop").disabled = d.state !== "running";
  $("drape-btn").disabled = d.state === "running";
  $("drape-progress").value = d.progress || 0;
  s.className = d.state;
  const result = $("drape-result");
  if (d.state === "idle") { s.textContent = "No drape yet."; result.textContent = ""; return; }
  if (d.state === "running") {
    s.textContent = `draping: frame ${d.done} of ${d.frames}, ${d.note}`;
    result.textContent = "";
    return;
  }
  s.textContent = d.state === "done" ? `done: ${d.frames} frames, ${d.note}` : `${d.state}: ${d.reason}`;
  result.textContent = "";
  const url = (p) => `/files/${p.split("/").map(encodeURIComponent).join("/")}?t=${Date.now()}`;
  for (const p of (d.pictures || []).filter((q) => !q.endsWith("-pattern.png"))) {
    // the still: front, back and side in the strain colours (a click opens it full size)
    const a = document.createElement("a");
    a.href = url(p); a.target = "_blank";
    const img = document.createElement("img");
    img.src = a.href; img.alt = p; img.className = "drape-still";
    a.appendChild(img);
    result.appendChild(a);
  }
  for (const p of (d.pictures || []).filter((q) => q.endsWith("-pattern.png"))) {
    const a = document.createElement("a");
    a.href = url(p); a.target = "_blank"; a.className = "drape-pattern";
    a.textContent = "the seam set-up picture";
    result.appendChild(a);
  }
  const rows = (d.quality || []).filter((l) => l.startsWith("|") && !/^\|[-|]+\|$/.test(l));
  if (rows.length) {
    const box = document.createElement("div");
    box.className = "table";
    const table = document.createElement("table");
    rows.forEach((line, i) => {
      const tr = document.createElement("tr");
      for (const cell of line.split("|").slice(1, -1)) {
        const td = document.createElement(i ? "td" : "th");
        td.textContent = cell.trim();
        tr.appendChild(td);
      }
      table.appendChild(tr);
    });
    box.appendChild(table);
    result.appendChild(box);
  }
  for (const line of (d.quality || []).filter((l) => !l.startsWith("|"))) {
    const p = document.createElement("p"); p.className = "hint"; p.textContent = line; result.appendChild(p);
  }
  if (d.open_command) {
    const p = document.createElement("p");
    p.textContent = "Open the recording (run this in the studio's folder):";
    const code = document.createElement("code");
    code.textContent = d.open_command;
    result.appendChild(p);
    result.appendChild(code);
  }
}

// ------------------------------------------------------------------------------------------------ the whole page
function render(s) {
  state = s;
  $("undo-btn").disabled = !s.undo;
  $("redo-btn").disabled = !s.redo;
  const r = $("restore");
  r.hidden = !s.restore;
  if (s.restore) $("restore-text").textContent = `An autosave of unsaved changes (written ${s.restore.written}` +
    `${s.restore.target ? ", of " + s.restore.target : ""}) was left by an earlier studio.`;
  if (!s.open) {
    $("file-info").textContent = "no pattern open: open or upload a DXF or garment file";
    drawPattern(); drawSeamList(); drawDrape(s.drape);
    return;
  }
  $("file-info").textContent = `${s.name} · ${s.source || ""} · ${s.units}` +
    (s.saved ? ` · saved as ${s.target}` : (s.autosave.current ? " · unsaved changes (autosaved)" : " · not saved")) +
    (s.autosave.error ? ` · ${s.autosave.error}` : "");
  if (changed("save", [s.target, s.target ? null : s.name])) $("save-path").value = s.target || `${s.name}.toml`;
  if (document.activeElement !== $("garment-name")) $("garment-name").value = s.name;
  for (const u of document.querySelectorAll(".unit")) u.textContent = s.units;
  if ($("drape-spacing").value === "") $("drape-spacing").value = Math.max(s.spacing, 0.04 / unitScale(s.units));
  if (selectedSeam !== null && selectedSeam >= s.seams.length) selectedSeam = null;
  // placement choices
  const plPiece = $("pl-piece"), keep = plPiece.value;
  plPiece.textContent = "";
  for (const p of s.pieces) plPiece.add(new Option(p.name, p.name));
  plPiece.value = s.pieces.some((p) => p.name === keep) ? keep : (s.pieces[0] || {}).name;
  const anchor = $("pl-anchor");
  if (!anchor.options.length) for (const a of s.anchors) anchor.add(new Option(a, a));
  fillPlacement();
  drawPattern();
  drawSeamList();
  drawPlacementTable();
  drawMaterial();
  drawDrape(s.drape);
  if (s.drape.state === "running") watchDrape();
  if (!$("tab-placement").hidden) loadPlacementPicture();
  pickHelp();
}

function unitScale(units) {
  return {m: 1, cm: 0.01, mm: 0.001, in: 0.0254}[units] || 1;
}

async function refresh() {
  const response = await fetch("/api/state");
  render(await response.json());
}

async function listFiles() {
  const r = await fetch("/api/files").then((x) => x.json()).catch(() => ({files: []}));
  const list = $("open-list");
  list.textContent = "";
  list.add(new Option("files in the folder…", ""));
  for (const f of r.files) list.add(new Option(f, f));
}

function showTab(name) {
  for (const b of document.querySelectorAll(".tabs button")) b.classList.toggle("active", b.dataset.tab === name);
  for (const t of document.querySelectorAll(".tab")) t.hidden = t.id !== `tab-${name}`;
  if (name === "placement") loadPlacementPicture();
}

async function save(overwrite) {
  const r = await api("POST", "/api/save", {path: $("save-path").value.trim() || null, overwrite});
  if (!r) return;
  if (r.status === 409 && /exists/.test(r.error || "") && !overwrite) {
    if (confirm(`${r.error}?`)) await save(true);
    return;
  }
  if (r.saved) { say(`saved ${r.saved}`, "info"); listFiles(); }
}

function wire() {
  for (const b of document.querySelectorAll(".tabs button")) b.addEventListener("click", () => showTab(b.dataset.tab));
  $("open-btn").addEventListener("click", async () => {
    const path = $("open-path").value.trim() || $("open-list").value;
    if (!path) { say("choose a file to open", "error"); return; }
    pick = null;
    const r = await api("POST", "/api/open", {path, units: $("open-units").value || null});
    if (r && r.state) say(`opened ${path}`, "info");
  });
  $("upload-input").addEventListener("change", async (ev) => {
    const file = ev.target.files[0];
    if (!file) return;
    const form = new FormData();
    form.append("file", file, file.name);
    if ($("open-units").value) form.append("units", $("open-units").value);
    const r = await api("POST", "/api/upload", form);
    ev.target.value = "";
    if (r && r.state) { say(`opened ${r.kept} (uploaded)`, "info"); listFiles(); }
  });
  $("undo-btn").addEventListener("click", () => api("POST", "/api/undo"));
  $("redo-btn").addEventListener("click", () => api("POST", "/api/redo"));
  $("save-btn").addEventListener("click", () => save(false));
  $("restore-btn").addEventListener("click", async () => {
    const r = await api("POST", "/api/restore");
    if (r && r.state) say("restored the autosave (Undo goes back)", "info");
  });
  $("dismiss-btn").addEventListener("click", () => api("POST", "/api/restore/dismiss"));
  $("garment-name").addEventListener("change", (ev) => api("POST", "/api/name", {name: ev.target.value}));
  $("pl-piece").addEventListener("change", () => selectPiece($("pl-piece").value));
  $("pl-apply").addEventListener("click", applyPlacement);
  $("pp-apply").addEventListener("click", applyPiecePattern);
  $("dxf-apply").addEventListener("click", applyDxfOptions);
  $("mat-apply").addEventListener("click", async () => {
    const values = {};
    for (const k of Object.keys(MATERIAL_UNITS)) values[k] = num(`mat-${k}`);
    const r = await api("PUT", "/api/material", {preset: $("mat-preset").value, values});
    if (r && r.state) say("material set", "info");
  });
  $("spacing-apply").addEventListener("click", async () => {
    const r = await api("PUT", "/api/spacing", {spacing: num("spacing")});
    if (r && r.state) say(`spacing ${r.state.spacing} ${r.state.units}: about ${r.state.particles} particles`, "info");
  });
  $("drape-btn").addEventListener("click", startDrape);
  $("drape-stop").addEventListener("click", () => fetch("/api/drape/cancel", {method: "POST"}));
  document.addEventListener("keydown", (ev) => {
    if (ev.key === "Escape" && pick) { pick = null; pickHelp(); drawPattern(); }
    if ((ev.ctrlKey || ev.metaKey) && ev.key === "z" && ev.target.tagName !== "INPUT") api("POST", "/api/undo");
    if ((ev.ctrlKey || ev.metaKey) && ev.key === "y" && ev.target.tagName !== "INPUT") api("POST", "/api/redo");
  });
}

wire();
listFiles();
refresh();
