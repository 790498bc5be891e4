// virtuose_demo page: polls /state.json (long poll), draws the scene with a
// small hand-written perspective renderer on a 2D canvas (no library, no
// CDN), plots force and loop rate, and exposes everything on
// window.demoState (read by the headless-Chromium test).
"use strict";

const demoState = {
  polls: 0, errors: 0, t: 0, done: false,
  handle: [0, 0, 0], coupled: [0, 0, 0], free: [0, 0, 0], force: [0, 0, 0],
  rateHz: 0, loopHz: 0, loss: 0, rttMs: 0,
  handleMin: null, handleMax: null, coupledMin: null, coupledMax: null,
  handleRange: 0, coupledRange: 0, freeRange: 0, freeMin: null, freeMax: null,
  couplingErrorMax: 0, couplingErrorLast: 0, frames: 0,
};
window.demoState = demoState;

let world = { radiusA: 0.03, radiusB: 0.04, floorZ: -0.1, halfWidth: 0.2 };
let history = [];

function track(minK, maxK, v) {
  if (!demoState[minK]) { demoState[minK] = v.slice(); demoState[maxK] = v.slice(); return; }
  for (let i = 0; i < 3; i++) {
    demoState[minK][i] = Math.min(demoState[minK][i], v[i]);
    demoState[maxK][i] = Math.max(demoState[maxK][i], v[i]);
  }
}
function range(minK, maxK) {
  if (!demoState[minK]) return 0;
  let r = 0;
  for (let i = 0; i < 3; i++) r = Math.max(r, demoState[maxK][i] - demoState[minK][i]);
  return r;
}
function dist(a, b) { return Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]); }

// ---- camera: orbit around the box centre, z up ----
const cam = { yaw: -0.6, pitch: 0.35, dist: 0.75, focal: 700 };
function project(p, cv) {
  const cy = Math.cos(cam.yaw), sy = Math.sin(cam.yaw);
  const cp = Math.cos(cam.pitch), sp = Math.sin(cam.pitch);
  // world (x right, y depth, z up) -> camera
  let x = cy * p[0] - sy * p[1];
  let y = sy * p[0] + cy * p[1];
  let z = p[2];
  const yc = cp * y - sp * z;
  const zc = sp * y + cp * z;
  const depth = yc + cam.dist;
  const s = cam.focal / Math.max(depth, 0.05);
  return { x: cv.width / 2 + x * s, y: cv.height / 2 - zc * s, depth, s };
}

function line(ctx, cv, a, b, color, w) {
  const p = project(a, cv), q = project(b, cv);
  ctx.strokeStyle = color; ctx.lineWidth = w || 1;
  ctx.beginPath(); ctx.moveTo(p.x, p.y); ctx.lineTo(q.x, q.y); ctx.stroke();
}

function sphere(ctx, cv, c, r, color) {
  const p = project(c, cv);
  const R = r * p.s;
  const g = ctx.createRadialGradient(p.x - R / 3, p.y - R / 3, R / 6, p.x, p.y, R);
  g.addColorStop(0, "#ffffff"); g.addColorStop(0.25, color); g.addColorStop(1, "#000000");
  ctx.fillStyle = g;
  ctx.beginPath(); ctx.arc(p.x, p.y, Math.max(R, 1), 0, 2 * Math.PI); ctx.fill();
}

function drawScene() {
  const cv = document.getElementById("scene");
  const ctx = cv.getContext("2d");
  ctx.clearRect(0, 0, cv.width, cv.height);
  const h = world.halfWidth, f = world.floorZ;
  // floor grid
  for (let i = -4; i <= 4; i++) {
    const u = (i / 4) * h;
    line(ctx, cv, [u, -h, f], [u, h, f], "#333a44");
    line(ctx, cv, [-h, u, f], [h, u, f], "#333a44");
  }
  // box edges
  const top = f + 2 * h;
  for (const [x, y] of [[-h, -h], [h, -h], [h, h], [-h, h]]) line(ctx, cv, [x, y, f], [x, y, top], "#3c4450");
  // shadows on the floor
  for (const [c, r] of [[demoState.coupled, world.radiusA], [demoState.free, world.radiusB]]) {
    const p = project([c[0], c[1], f], cv);
    ctx.fillStyle = "rgba(0,0,0,0.45)";
    ctx.beginPath(); ctx.ellipse(p.x, p.y, r * p.s, r * p.s * 0.4, 0, 0, 2 * Math.PI); ctx.fill();
  }
  // spheres, far first
  const items = [
    { c: demoState.coupled, r: world.radiusA, col: "#4aa3ff" },
    { c: demoState.free, r: world.radiusB, col: "#ff9f43" },
  ].sort((a, b) => project(b.c, cv).depth - project(a.c, cv).depth);
  for (const it of items) sphere(ctx, cv, it.c, it.r, it.col);
  // coupling spring handle -> A, handle cross, force arrow
  line(ctx, cv, demoState.handle, demoState.coupled, "#ffe066", 1);
  const hd = demoState.handle, k = 0.012;
  line(ctx, cv, [hd[0] - k, hd[1], hd[2]], [hd[0] + k, hd[1], hd[2]], "#ffe066", 3);
  line(ctx, cv, [hd[0], hd[1] - k, hd[2]], [hd[0], hd[1] + k, hd[2]], "#ffe066", 3);
  line(ctx, cv, [hd[0], hd[1], hd[2] - k], [hd[0], hd[1], hd[2] + k], "#ffe066", 3);
  const fs = 0.01; // m per N
  const a = demoState.coupled, F = demoState.force;
  line(ctx, cv, a, [a[0] + F[0] * fs, a[1] + F[1] * fs, a[2] + F[2] * fs], "#ff6b6b", 2);
  demoState.frames++;
}

function plot(id, series, colors, ymin, ymax) {
  const cv = document.getElementById(id);
  const ctx = cv.getContext("2d");
  ctx.clearRect(0, 0, cv.width, cv.height);
  if (history.length < 2) return;
  let lo = ymin, hi = ymax;
  for (const s of series) for (const row of history) { lo = Math.min(lo, row[s]); hi = Math.max(hi, row[s]); }
  if (hi - lo < 1e-9) hi = lo + 1;
  const t0 = history[0][0], t1 = history[history.length - 1][0];
  const X = (t) => ((t - t0) / Math.max(t1 - t0, 1e-3)) * (cv.width - 40) + 35;
  const Y = (v) => cv.height - 15 - ((v - lo) / (hi - lo)) * (cv.height - 25);
  ctx.strokeStyle = "#444"; ctx.beginPath(); ctx.moveTo(35, Y(0)); ctx.lineTo(cv.width, Y(0)); ctx.stroke();
  ctx.fillStyle = "#aaa"; ctx.font = "11px sans-serif";
  ctx.fillText(hi.toFixed(1), 2, 12); ctx.fillText(lo.toFixed(1), 2, cv.height - 16);
  series.forEach((s, i) => {
    ctx.strokeStyle = colors[i]; ctx.lineWidth = 1.5; ctx.beginPath();
    history.forEach((row, j) => { const x = X(row[0]), y = Y(row[s]); if (j) ctx.lineTo(x, y); else ctx.moveTo(x, y); });
    ctx.stroke();
  });
}

function update(st) {
  world = st.world;
  history = st.history;
  const n = st.now;
  Object.assign(demoState, {
    t: n.t, done: st.done, handle: n.handle, coupled: n.coupled, free: n.free, force: n.force,
    rateHz: n.rateHz, loopHz: n.loopHz, loss: n.loss, rttMs: n.rttMs, answers: n.answers, power: n.power,
  });
  demoState.polls++;
  if (n.answers > 0) {
    track("handleMin", "handleMax", n.handle);
    track("coupledMin", "coupledMax", n.coupled);
    track("freeMin", "freeMax", n.free);
    demoState.handleRange = range("handleMin", "handleMax");
    demoState.coupledRange = range("coupledMin", "coupledMax");
    demoState.freeRange = range("freeMin", "freeMax");
    demoState.couplingErrorLast = dist(n.handle, n.coupled);
    if (n.t > 1.0) demoState.couplingErrorMax = Math.max(demoState.couplingErrorMax, demoState.couplingErrorLast);
  }
  const server = document.getElementById("server");
  server.textContent = "controller: " + st.server + (st.done ? " (run finished)" : "");
  if (st.report) {
    const a = document.createElement("a");
    a.href = "report/summary.html";
    a.textContent = "run report";
    server.append(" — ", a);
  }
  demoState.report = !!st.report;
  document.getElementById("info").textContent =
    `t = ${n.t.toFixed(1)} s   power ${n.power ? "on" : "off"}\n` +
    `answers ${n.rateHz.toFixed(0)} Hz   loss ${(n.loss * 100).toFixed(3)} %   rtt ${n.rttMs.toFixed(3)} ms\n` +
    `handle  (${n.handle.map((v) => v.toFixed(4)).join(", ")}) m\n` +
    `sphere A (${n.coupled.map((v) => v.toFixed(4)).join(", ")}) m\n` +
    `sphere B (${n.free.map((v) => v.toFixed(4)).join(", ")}) m\n` +
    `force   (${n.force.map((v) => v.toFixed(2)).join(", ")}) N`;
  drawScene();
  plot("force", [1, 2, 3], ["#ff6b6b", "#7bd389", "#6bb6ff"], -1, 1);
  plot("rate", [4], ["#9fd3ff"], 0, 1100);
  document.getElementById("state").textContent = JSON.stringify(demoState);
}

let since = -1;
async function poll() {
  try {
    const r = await fetch("state.json?since=" + since, { cache: "no-store" });
    const st = await r.json();
    since = st.now.t;
    update(st);
  } catch (e) {
    demoState.errors++;
  }
  // After the run, poll slowly until the report is there.
  if (!demoState.done) setTimeout(poll, 50);
  else if (!demoState.report) setTimeout(poll, 1000);
}
poll();
