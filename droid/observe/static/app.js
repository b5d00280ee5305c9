// droid-web page: status tables, plots, and a three.js view of the cell (docs/observe.md): the arms'
// bodies, tool, sensor and laser sheet, the workpiece's surfaces, the seam map, force arrows, the collision
// guard's closest pair; camera presets.
// Read-only: the WebSocket only receives; the slider (recordings) uses GET /api/frame.
import * as THREE from "three";
import { OrbitControls } from "./vendor/three/OrbitControls.js";

const q = new URLSearchParams(location.search);
const token = q.get("token");
const withToken = (u) => token ? u + (u.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(token) : u;
const $ = (id) => document.getElementById(id);
const state = { mode: null, snapshots: 0, lastTick: null, ticks: [], seam: [], cell: null };
window.droidState = state;  // for the browser test and curious users

// ---------------------------------------------------------------- 3-D view (z up, mm)
const canvas = $("canvas3d");
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
renderer.setClearColor(0x1b2026);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(45, 1, 10, 20000);
camera.up.set(0, 0, 1);
camera.position.set(1000, -2500, 1700);
const controls = new OrbitControls(camera, canvas);
controls.target.set(1000, 0, 800);
controls.update();
scene.add(new THREE.AmbientLight(0xffffff, 0.7));
const sun = new THREE.DirectionalLight(0xffffff, 1.2); sun.position.set(1000, -2000, 3000); scene.add(sun);
const grid = new THREE.GridHelper(4000, 40, 0x445566, 0x2a333d); grid.rotation.x = Math.PI / 2; grid.position.x = 1000; scene.add(grid);
scene.add(new THREE.AxesHelper(300));

// Bodies (issue 29): every capsule [x0,y0,z0,x1,y1,z1,r] the server sends, drawn as a cylinder and two balls.
const bodyColors = { arm1: 0x3d8fe0, gmf1: 0x5fb14e, torch: 0xd0d4da, bracket: 0x6c7480, fixture: 0x47803a };
const spareColors = [0xb07fe0, 0xe07f9a, 0x7fd0e0];
const unitCyl = new THREE.CylinderGeometry(1, 1, 1, 20, 1, true), unitBall = new THREE.SphereGeometry(1, 20, 12);
const bodies = {};  // name -> {mat, parts: [{cyl, a, b}]}
function bodyGroup(name) {
  if (bodies[name]) return bodies[name];
  const color = bodyColors[name] ?? spareColors[Object.keys(bodies).length % spareColors.length];
  return (bodies[name] = { mat: new THREE.MeshStandardMaterial({ color, roughness: 0.55, metalness: 0.15 }), parts: [] });
}
const _up = new THREE.Vector3(0, 1, 0), _d = new THREE.Vector3();
function drawBodies(all) {
  for (const [name, caps] of Object.entries(all || {})) {
    const g = bodyGroup(name);
    while (g.parts.length < caps.length) {
      const part = { cyl: new THREE.Mesh(unitCyl, g.mat), a: new THREE.Mesh(unitBall, g.mat), b: new THREE.Mesh(unitBall, g.mat) };
      scene.add(part.cyl, part.a, part.b); g.parts.push(part);
    }
    g.parts.forEach((part, i) => {
      const c = caps[i];
      const on = c !== undefined;
      part.cyl.visible = part.a.visible = part.b.visible = on;
      if (!on) return;
      part.a.visible = i > 0;  // a group's first capsule starts at its base or mount: drawn flat there
      const r = c[6];
      part.a.position.set(c[0], c[1], c[2]); part.a.scale.setScalar(r);
      part.b.position.set(c[3], c[4], c[5]); part.b.scale.setScalar(r);
      _d.set(c[3] - c[0], c[4] - c[1], c[5] - c[2]);
      const len = _d.length();
      part.cyl.visible = len > 0.5;
      if (len > 0.5) {
        part.cyl.position.set((c[0] + c[3]) / 2, (c[1] + c[4]) / 2, (c[2] + c[5]) / 2);
        part.cyl.quaternion.setFromUnitVectors(_up, _d.divideScalar(len));
        part.cyl.scale.set(r, len, r);
      }
    });
  }
}
function frameAxes(size) { const a = new THREE.AxesHelper(size); a.matrixAutoUpdate = false; a.visible = false; scene.add(a); return a; }
const axes = {};

// The workpiece: its surfaces from the scene data (/api/cell scene.workpiece_mesh, in W), else a plate.
const WP = { lower: new THREE.Color(0xc08a4e), edge: new THREE.Color(0x8a5a2c), upper: new THREE.Color(0xe0b47a), tack: new THREE.Color(0xff7a1a) };
const workpiece = new THREE.Group(); workpiece.matrixAutoUpdate = false; workpiece.visible = false; scene.add(workpiece);
const wpMaterial = new THREE.MeshStandardMaterial({ vertexColors: true, side: THREE.DoubleSide, roughness: 0.8 });
function plateMesh() {
  const g = new THREE.BoxGeometry(400, 200, 10); g.translate(200, 0, -5);
  return new THREE.Mesh(g, new THREE.MeshStandardMaterial({ color: WP.lower, transparent: true, opacity: 0.85 }));
}
function workpieceMesh(m) {
  // sections of six points: strips lower surface, edge face, tack top, tack side, upper surface
  const N = m.sections, K = m.per_section, P = m.points;
  const strips = 5, pos = new Float32Array(N * strips * 2 * 3), col = new Float32Array(N * strips * 2 * 3), idx = [];
  let v = 0;
  for (let j = 0; j < strips; j++) {
    for (let i = 0; i < N; i++) {
      const c = j === 0 ? WP.lower : j === 1 ? WP.edge : j === 4 ? WP.upper : (m.tack[i] ? WP.tack : WP.upper);
      for (const k of [j, j + 1]) {
        pos.set(P.slice(3 * (i * K + k), 3 * (i * K + k) + 3), 3 * v); col.set([c.r, c.g, c.b], 3 * v); v++;
      }
      if (i > 0) { const a = v - 4, b = v - 3, c2 = v - 2, d = v - 1; idx.push(a, c2, b, b, c2, d); }
    }
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.BufferAttribute(pos, 3)); g.setAttribute("color", new THREE.BufferAttribute(col, 3));
  g.setIndex(idx); g.computeVertexNormals();
  return new THREE.Mesh(g, wpMaterial);
}
function setWorkpiece(sceneData) {
  workpiece.clear();
  const m = sceneData && sceneData.workpiece_mesh;
  workpiece.add(m ? workpieceMesh(m) : plateMesh());
  state.workpiece = m ? m.name : "plate";
}

const toolPoint = new THREE.Mesh(new THREE.SphereGeometry(8, 12, 8), new THREE.MeshStandardMaterial({ color: 0xffffff, emissive: 0x444444 }));
toolPoint.visible = false; scene.add(toolPoint);
// the lead sensor's head (behind its laser's source, in the sensor frame) and its laser sheet
const sensorHead = new THREE.Mesh(new THREE.BoxGeometry(70, 90, 50).translate(-35, 0, 0), new THREE.MeshStandardMaterial({ color: 0x30343a, roughness: 0.4 }));
sensorHead.matrixAutoUpdate = false; sensorHead.visible = false; scene.add(sensorHead);
const laserGeom = new THREE.BufferGeometry(); laserGeom.setAttribute("position", new THREE.BufferAttribute(new Float32Array(6), 3));
const laser = new THREE.Line(laserGeom, new THREE.LineBasicMaterial({ color: 0xff2020 })); laser.visible = false; laser.frustumCulled = false; scene.add(laser);
const sheetGeom = new THREE.BufferGeometry(); sheetGeom.setAttribute("position", new THREE.BufferAttribute(new Float32Array(9), 3));
const sheet = new THREE.Mesh(sheetGeom, new THREE.MeshBasicMaterial({ color: 0xff3030, transparent: true, opacity: 0.25, side: THREE.DoubleSide, depthWrite: false }));
sheet.visible = false; sheet.frustumCulled = false; scene.add(sheet);
const SEAM_MAX = 20000;
const seamGeom = new THREE.BufferGeometry(); seamGeom.setAttribute("position", new THREE.BufferAttribute(new Float32Array(3 * SEAM_MAX), 3));
seamGeom.setDrawRange(0, 0);
const seamLine = new THREE.Line(seamGeom, new THREE.LineBasicMaterial({ color: 0xffee00 })); seamLine.frustumCulled = false; scene.add(seamLine);
// force arrows: one per subunit whose Status has force_N (drawn at the tool, FORCE_MM_PER_N long, unlit magenta)
const FORCE_MM_PER_N = 2.0, forces = {};
const arrowMat = new THREE.MeshBasicMaterial({ color: 0xff30ff });
const arrowShaft = new THREE.CylinderGeometry(1, 1, 1, 12).translate(0, 0.5, 0), arrowHead = new THREE.ConeGeometry(1, 1, 16).translate(0, -0.5, 0);
function arrowObject() {
  const g = new THREE.Group(), shaft = new THREE.Mesh(arrowShaft, arrowMat), head = new THREE.Mesh(arrowHead, arrowMat);
  g.add(shaft, head); scene.add(g);
  return { g, shaft, head };
}
function drawForces(list) {
  const seen = new Set();
  for (const f of list || []) {
    const v = new THREE.Vector3(...f.force_N), n = v.length();
    if (n < 1e-9) continue;
    seen.add(f.subunit);
    const a = forces[f.subunit] || (forces[f.subunit] = arrowObject());
    const len = Math.min(800, Math.max(30, n * FORCE_MM_PER_N)), head = Math.min(60, 0.3 * len);
    a.g.position.set(...f.at); a.g.quaternion.setFromUnitVectors(_up, v.divideScalar(n));
    a.shaft.scale.set(7, len - head, 7); a.head.scale.set(20, head, 20); a.head.position.set(0, len, 0);
  }
  for (const [k, a] of Object.entries(forces)) a.g.visible = seen.has(k);
  state.forces = [...seen];
}

function setSeam(points, from = 0) {
  const a = seamGeom.attributes.position.array;
  for (let i = 0; i < points.length && from + i < SEAM_MAX; i++) a.set(points[i], 3 * (from + i));
  state.seam.length = Math.min(from, state.seam.length); for (const p of points) state.seam.push(p);
  seamGeom.setDrawRange(0, Math.min(state.seam.length, SEAM_MAX));
  seamGeom.attributes.position.needsUpdate = true;
}
function matrixOf(m16) { const m = new THREE.Matrix4(); m.set(...m16); return m; }

// The collision guard's closest pair (docs/guard.md §7a): a line between its two closest points, coloured by state.
const GUARD_COLORS = { clear: 0x40e070, slowing: 0xffb020, stopped: 0xff3030 };
const guardGeom = new THREE.BufferGeometry(); guardGeom.setAttribute("position", new THREE.BufferAttribute(new Float32Array(6), 3));
const guardMat = new THREE.LineBasicMaterial({ color: GUARD_COLORS.clear, depthTest: false });
const guardLine = new THREE.Line(guardGeom, guardMat); guardLine.visible = false; guardLine.frustumCulled = false; guardLine.renderOrder = 10; scene.add(guardLine);
const guardEnds = [0, 1].map(() => { const m = new THREE.Mesh(new THREE.SphereGeometry(10, 12, 8), guardMat); m.visible = false; scene.add(m); return m; });
const fmt = (v, nd = 1) => (v == null ? "–" : Number(v).toFixed(nd));
function drawGuard(g) {
  state.guard = g || null;
  const on = !!(g && g.points && g.state !== "off");
  guardLine.visible = on; guardEnds.forEach((m) => { m.visible = on; });
  if (on) {
    guardGeom.attributes.position.array.set([...g.points[0], ...g.points[1]]); guardGeom.attributes.position.needsUpdate = true;
    guardMat.color.setHex(GUARD_COLORS[g.state] ?? 0xffffff);
    guardEnds[0].position.set(...g.points[0]); guardEnds[1].position.set(...g.points[1]);
  }
  const tag = $("guard-state");
  if (!g || g.state === "off") {
    tag.textContent = "off"; tag.className = "tag";
    $("guard-text").textContent = g && g.why ? g.why : "no collision guard";
    $("guard-override").tBodies[0].innerHTML = "";
    return;
  }
  tag.textContent = g.state + (g.stale ? " (STALE)" : "");
  tag.className = "tag " + (g.stale || g.state === "stopped" ? "bad" : g.state === "slowing" ? "warn" : "ok");
  const pair = g.pair ? g.pair.map((b) => `${b.arm} ${b.body}`).join(" with ") : "–";
  $("guard-text").textContent = `least ${fmt(g.distance_mm)} mm: ${pair}; closing ${fmt(g.closing_mm_s, 0)} mm/s, ` +
    `S_p ${fmt(g.separation_mm)} mm, trips ${g.trips ?? "–"}`;
  $("guard-override").tBodies[0].innerHTML = Object.entries(g.override || {}).map(([a, v]) =>
    `<tr data-arm="${esc(a)}"><td>override ${esc(a)}</td><td class="${v != null && v < 1 ? "bad" : "ok"}">${fmt(v, 2)}</td></tr>`).join("");
}

function drawGeo(geo) {
  drawBodies(geo.bodies);
  for (const [name, m16] of Object.entries(geo.frames || {})) {
    if (name === "workpiece") { workpiece.matrix.copy(matrixOf(m16)); workpiece.visible = true; continue; }
    const ax = axes[name] || (axes[name] = frameAxes(name.endsWith("/base") ? 250 : 80));
    ax.matrix.copy(matrixOf(m16)); ax.visible = true;
  }
  if (geo.tool) { toolPoint.position.set(...geo.tool); toolPoint.visible = true; followTool(geo.tool); }
  if (geo.frames && geo.frames.sensor && geo.laser_src) {
    sensorHead.matrix.copy(matrixOf(geo.frames.sensor)).setPosition(...geo.laser_src); sensorHead.visible = true;
  }
  if (geo.laser) {
    laserGeom.attributes.position.array.set([...geo.laser[0], ...geo.laser[1]]); laserGeom.attributes.position.needsUpdate = true; laser.visible = true;
    if (geo.laser_src) {
      sheetGeom.attributes.position.array.set([...geo.laser_src, ...geo.laser[0], ...geo.laser[1]]); sheetGeom.attributes.position.needsUpdate = true; sheet.visible = true;
    }
  } else { laser.visible = false; sheet.visible = false; }
  drawForces(geo.forces);
}

// Camera presets (buttons, and the URL hash: #view=cell|tool|side); "tool" follows the tool point.
const VIEWS = {
  cell: { pos: [1900, -3300, 2300], target: [900, 0, 700] },
  side: { pos: [1000, -4300, 900], target: [1000, 0, 900] },
  tool: { offset: [250, -520, 60] },
};
let view = "cell", lastTool = null;
function setView(name) {
  if (!VIEWS[name]) name = "cell";
  view = name;
  const v = VIEWS[name];
  if (name === "tool") {
    const t = lastTool || [300, 100, 1100];
    controls.target.set(...t); camera.position.set(t[0] + v.offset[0], t[1] + v.offset[1], t[2] + v.offset[2]);
  } else { controls.target.set(...v.target); camera.position.set(...v.pos); }
  controls.update();
  for (const b of document.querySelectorAll("#views button")) b.classList.toggle("on", b.dataset.view === name);
  const h = new URLSearchParams(location.hash.slice(1));
  if (h.get("view") !== name) { h.set("view", name); history.replaceState(null, "", "#" + h.toString()); }
  droidView.view = name;
}
function followTool(t) {
  if (view === "tool" && lastTool) {
    const d = [t[0] - lastTool[0], t[1] - lastTool[1], t[2] - lastTool[2]];
    controls.target.x += d[0]; controls.target.y += d[1]; controls.target.z += d[2];
    camera.position.x += d[0]; camera.position.y += d[1]; camera.position.z += d[2];
  }
  const first = lastTool === null;
  lastTool = [...t];
  if (first && view === "tool") setView("tool");
}
// A hook for tests and scripts: the page's camera projection and its view.
const droidView = window.droidView = {
  view, rendered: 0, setView, FORCE_MM_PER_N,
  // a global point [mm] -> [x, y] in CSS pixels of the 3-D canvas (its top-left corner at 0, 0)
  draw(geo) { drawGeo(geo); },  // draw a scene payload (``geo`` of a snapshot), e.g. a synthetic one
  guard: () => ({ visible: guardLine.visible, color: guardMat.color.getHex(),
                  points: [0, 1].map((i) => [0, 1, 2].map((k) => guardGeom.attributes.position.array[3 * i + k])) }),
  project(p) {
    const v = new THREE.Vector3(...p).project(camera);
    return [(v.x + 1) / 2 * canvas.clientWidth, (1 - v.y) / 2 * canvas.clientHeight, v.z];
  },
};
for (const b of document.querySelectorAll("#views button")) b.addEventListener("click", () => setView(b.dataset.view));
window.addEventListener("hashchange", () => setView(new URLSearchParams(location.hash.slice(1)).get("view") || "cell"));
setView(new URLSearchParams(location.hash.slice(1)).get("view") || "cell");

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== w || canvas.height !== h) { renderer.setSize(w, h, false); camera.aspect = w / Math.max(h, 1); camera.updateProjectionMatrix(); }
}
function animate() { resize(); controls.update(); renderer.render(scene, camera); droidView.rendered++; requestAnimationFrame(animate); }
requestAnimationFrame(animate);

// ---------------------------------------------------------------- tables, plots, log
const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
function drawTables(snap) {
  const rows = Object.entries(snap.subunits).map(([n, s]) => {
    const homed = s.arm ? (s.homed ? "yes" : "no") : (s.valid ? "valid" : "invalid");
    return `<tr data-subunit="${esc(n)}"><td>${esc(n)}</td><td class="tick">${s.tick}</td><td>${homed}</td><td>${s.busy}</td>` +
      `<td>${esc(s.mode)}</td><td class="${s.stale ? "bad" : "ok"}">${s.stale ? "STALE" : "fresh"}</td>` +
      `<td class="${s.fault.length ? "bad" : ""}">${esc(s.fault.join(",") || "–")}</td>` +
      `<td class="${s.cmd_result === "ok" ? "" : "bad"}">${esc(s.cmd_result)}</td></tr>`;
  });
  $("subunits").tBodies[0].innerHTML = rows.join("");
  const h = snap.health || {};
  $("health").tBodies[0].innerHTML = (h.programs || []).map((p) =>
    `<tr><td>${esc(p.name)}</td><td>${esc(p.state)}</td><td class="${p.live ? "ok" : "bad"}">${p.live ? "live" : "no"}</td>` +
    `<td>${p.last_tick ?? "–"}</td><td>${p.overruns ?? "–"}</td><td>${p.bad_frames ?? "–"}</td></tr>`).join("");
  const hb = h.heartbeat || {};
  $("lateness").textContent = hb.lateness_max_ns != null ? (hb.lateness_max_ns / 1e6).toFixed(2) : "–";
  $("overruns").textContent = hb.overruns ?? "–";
}
const PLOT_N = 600;
const series = { tool_lateral_mm: [], tool_height_mm: [], lead_lateral_mm: [], speed_mm_s: [] };
const colors = { tool_lateral_mm: "#4fa3ff", tool_height_mm: "#8fdc6f", lead_lateral_mm: "#ffcc00", speed_mm_s: "#ff8c5a" };
function pushPlots(p) { for (const k in series) { series[k].push(p[k]); if (series[k].length > PLOT_N) series[k].shift(); } }
function plot(id, keys, unit) {
  const c = $(id), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  let lo = Infinity, hi = -Infinity;
  for (const k of keys) for (const v of series[k]) if (v != null) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!isFinite(lo)) { lo = -1; hi = 1; }
  if (hi - lo < 1e-6) { lo -= 1; hi += 1; }
  const y = (v) => c.height - 14 - (v - lo) / (hi - lo) * (c.height - 24);
  g.font = "10px monospace"; g.fillStyle = "#889";
  g.fillText(`${hi.toFixed(2)} ${unit}`, 2, 10); g.fillText(`${lo.toFixed(2)} ${unit}`, 2, c.height - 2);
  keys.forEach((k, j) => {
    g.strokeStyle = colors[k]; g.beginPath(); let pen = false;
    series[k].forEach((v, i) => { const x = i * c.width / PLOT_N; if (v == null) { pen = false; return; } pen ? g.lineTo(x, y(v)) : g.moveTo(x, y(v)); pen = true; });
    g.stroke(); g.fillStyle = colors[k]; g.fillText(k, 120 + j * 120, 10);
  });
}
function drawLogs(logs) {
  if (!logs) return;
  $("logs").innerHTML = logs.slice(-30).reverse().map((l) => `<li>${l.tick} ${esc(l.name)}: ${esc(l.message)}</li>`).join("");
}

let updates = 0;
setInterval(() => { $("fps").textContent = updates; state.fps = updates; updates = 0; }, 1000);
function show(snap) {
  state.snapshots++; updates++;
  state.lastTick = snap.tick; state.ticks = Object.fromEntries(Object.entries(snap.subunits).map(([n, s]) => [n, s.tick]));
  $("tick").textContent = snap.tick;
  drawTables(snap); drawGeo(snap.geo); drawGuard(snap.guard);
  if (snap.seam) setSeam(snap.seam, snap.seam_from ?? 0);
  if (snap.logs) drawLogs(snap.logs);
}

// ---------------------------------------------------------------- data sources
async function getJSON(u) { const r = await fetch(withToken(u)); if (!r.ok) throw new Error(`${u}: HTTP ${r.status}`); return r.json(); }

async function openFile(info) {
  $("slider-row").hidden = false;
  const s = $("slider"); s.max = info.file.count - 1; $("slider-max").textContent = info.file.count - 1;
  for (const k in series) series[k] = [];
  let pending = null, busy = false;
  async function go(i) {
    if (busy) { pending = i; return; }
    busy = true;
    try {
      const snap = await getJSON(`api/frame?i=${i}&seam_from=${state.seam.length}`);
      $("slider-tick").textContent = snap.tick; $("slider-pos").textContent = snap.index;
      state.index = snap.index;
      show(snap);
    } finally { busy = false; if (pending !== null) { const p = pending; pending = null; go(p); } }
  }
  // plots of the whole recording: sample the frames once
  const pl = await getJSON(`api/plots?n=${PLOT_N}`);
  for (const p of pl.plots) pushPlots(p);
  plot("plot-errors", ["tool_lateral_mm", "tool_height_mm", "lead_lateral_mm"], "mm"); plot("plot-speed", ["speed_mm_s"], "mm/s");
  s.addEventListener("input", () => go(Number(s.value)));
  s.value = 0; await go(0);
  // play: 30 updates/s at the recording's pace (every heartbeat_hz/30-th tick), looping; #play=1 starts it
  const stride = Math.max(1, Math.round((info.heartbeat_hz || 60) / 30));
  let timer = null;
  const play = $("play");
  function toggle(on) {
    if (on && !timer) timer = setInterval(() => { if (!busy) { const i = (Number(s.value) + stride) % (info.file.count); s.value = i; go(i); } }, 1000 / 30);
    else if (!on && timer) { clearInterval(timer); timer = null; }
    play.textContent = timer ? "❚❚" : "▶"; state.playing = !!timer;
  }
  play.addEventListener("click", () => toggle(!timer));
  if (new URLSearchParams(location.hash.slice(1)).get("play") === "1") toggle(true);
  $("conn").textContent = "recording"; $("conn").className = "tag ok";
}

function openLive() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(withToken(`${proto}//${location.host}/ws`));
  ws.onopen = () => { $("conn").textContent = "live"; $("conn").className = "tag ok"; };
  ws.onclose = () => { $("conn").textContent = "disconnected"; $("conn").className = "tag bad"; setTimeout(openLive, 1000); };
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data);
    if (m.type === "seam") setSeam(m.points, m.from);
    else if (m.type === "snapshot") { show(m); pushPlots(m.plots); }
  };
  setInterval(() => { plot("plot-errors", ["tool_lateral_mm", "tool_height_mm", "lead_lateral_mm"], "mm"); plot("plot-speed", ["speed_mm_s"], "mm/s"); }, 200);
}

(async () => {
  const info = await getJSON("api/cell");
  state.cell = info; state.mode = info.source;
  setWorkpiece(info.scene);
  $("cell").textContent = info.cell; $("mode").textContent = info.source === "file" ? `recording (${info.recording_source})` : "live";
  if (info.source === "file") await openFile(info); else openLive();
  state.ready = true;
})().catch((e) => { console.error(e); $("conn").textContent = String(e); $("conn").className = "tag bad"; });
