// droid-web page: status tables, plots, and a three.js view of the cell (docs/observe.md).
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

const armColors = [0x4fa3ff, 0xffa64f, 0x8fdc6f, 0xd98cff];
const arms = {};
function armObject(name) {
  if (arms[name]) return arms[name];
  const color = armColors[Object.keys(arms).length % armColors.length];
  const geom = new THREE.BufferGeometry();
  geom.setAttribute("position", new THREE.BufferAttribute(new Float32Array(3 * 8), 3));
  const line = new THREE.Line(geom, new THREE.LineBasicMaterial({ color, linewidth: 3 }));
  const joints = [];
  for (let i = 0; i < 8; i++) {
    const s = new THREE.Mesh(new THREE.SphereGeometry(i === 0 ? 60 : 35, 12, 8), new THREE.MeshStandardMaterial({ color }));
    s.visible = false; scene.add(s); joints.push(s);
  }
  line.frustumCulled = false;
  scene.add(line);
  return (arms[name] = { line, joints });
}
function frameAxes(size) { const a = new THREE.AxesHelper(size); a.matrixAutoUpdate = false; a.visible = false; scene.add(a); return a; }
const axes = {};
const workpiece = new THREE.Mesh(new THREE.BoxGeometry(400, 200, 10), new THREE.MeshStandardMaterial({ color: 0x9aa0aa, transparent: true, opacity: 0.8 }));
workpiece.geometry.translate(200, 0, -5); workpiece.matrixAutoUpdate = false; workpiece.visible = false; scene.add(workpiece);
const toolPoint = new THREE.Mesh(new THREE.SphereGeometry(12, 12, 8), new THREE.MeshStandardMaterial({ color: 0xffffff, emissive: 0x444444 }));
toolPoint.visible = false; scene.add(toolPoint);
const laserGeom = new THREE.BufferGeometry(); laserGeom.setAttribute("position", new THREE.BufferAttribute(new Float32Array(6), 3));
const laser = new THREE.Line(laserGeom, new THREE.LineBasicMaterial({ color: 0xff2020 })); laser.visible = false; laser.frustumCulled = false; scene.add(laser);
const SEAM_MAX = 20000;
const seamGeom = new THREE.BufferGeometry(); seamGeom.setAttribute("position", new THREE.BufferAttribute(new Float32Array(3 * SEAM_MAX), 3));
seamGeom.setDrawRange(0, 0);
const seamLine = new THREE.Line(seamGeom, new THREE.LineBasicMaterial({ color: 0xffcc00 })); seamLine.frustumCulled = false; scene.add(seamLine);

function setSeam(points, from = 0) {
  const a = seamGeom.attributes.position.array;
  for (let i = 0; i < points.length && from + i < SEAM_MAX; i++) a.set(points[i], 3 * (from + i));
  state.seam.length = from; for (const p of points) state.seam.push(p);
  seamGeom.setDrawRange(0, Math.min(state.seam.length, SEAM_MAX));
  seamGeom.attributes.position.needsUpdate = true;
}
function matrixOf(m16) { const m = new THREE.Matrix4(); m.set(...m16); return m; }

function drawGeo(geo) {
  for (const [name, pts] of Object.entries(geo.links || {})) {
    const o = armObject(name);
    const a = o.line.geometry.attributes.position.array;
    pts.forEach((p, i) => { a.set(p, 3 * i); o.joints[i].position.set(...p); o.joints[i].visible = true; });
    o.line.geometry.setDrawRange(0, pts.length);
    o.line.geometry.attributes.position.needsUpdate = true;
  }
  for (const [name, m16] of Object.entries(geo.frames || {})) {
    if (name === "workpiece") { workpiece.matrix.copy(matrixOf(m16)); workpiece.visible = true; continue; }
    const ax = axes[name] || (axes[name] = frameAxes(name.endsWith("/base") ? 250 : 120));
    ax.matrix.copy(matrixOf(m16)); ax.visible = true;
  }
  if (geo.tool) { toolPoint.position.set(...geo.tool); toolPoint.visible = true; }
  if (geo.laser) { laserGeom.attributes.position.array.set([...geo.laser[0], ...geo.laser[1]]); laserGeom.attributes.position.needsUpdate = true; laser.visible = true; }
  else laser.visible = false;
}

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== w || canvas.height !== h) { renderer.setSize(w, h, false); camera.aspect = w / Math.max(h, 1); camera.updateProjectionMatrix(); }
}
function animate() { resize(); controls.update(); renderer.render(scene, camera); requestAnimationFrame(animate); }
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
  drawTables(snap); drawGeo(snap.geo);
  if (snap.seam) setSeam(snap.seam, 0);
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
      const snap = await getJSON(`api/frame?i=${i}`);
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
  $("cell").textContent = info.cell; $("mode").textContent = info.source === "file" ? `recording (${info.recording_source})` : "live";
  if (info.source === "file") await openFile(info); else openLive();
  state.ready = true;
})().catch((e) => { console.error(e); $("conn").textContent = String(e); $("conn").className = "tag bad"; });
