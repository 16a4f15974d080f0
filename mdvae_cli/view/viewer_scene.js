/* mdvae view, part 2 of 4: the state, the camera and the 3-D scene on a 2-D canvas. */
// ---------------------------------------------------------------- state
let tracks = [];
const state = {
  time: 0, playing: false, speed: 1, layout: "side", body: "both", follow: true, loop: true,
  last: null, dirty: true, duration: 0, fpsMax: 30, frames: 1, kind: "rotation", joint: 4, window: 0,
};
const cam = { yaw: 0, pitch: 0.28, dist: 4.6, fov: 0.62, home: 0, fixed: [] };
let plotCache = null;

// ---------------------------------------------------------------- camera
const DIST0 = cam.dist; // the distance a body is framed at before any zoom, metres
const HALF_WIDTH = 0.8; // what a panel shows each side of its aim at DIST0, at the least (m)
/* a panel's camera on target; ``fit`` (>= 1) moves it back until a group spread over the
   floor is in view. The focal length keeps a narrow panel's body whole across. */
function camera(target, x, y, w, h, fit = 1) {
  const cp = Math.cos(cam.pitch), dist = cam.dist * fit;
  const eye = [target[0] + dist * cp * Math.cos(cam.yaw), target[1] + dist * cp * Math.sin(cam.yaw),
    target[2] + dist * Math.sin(cam.pitch)];
  const f = norm(sub(target, eye)), r = norm(cross(f, [0, 0, 1])), u = cross(r, f);
  const focal = Math.min((0.5 * h) / Math.tan(cam.fov / 2), (0.5 * w * DIST0) / HALF_WIDTH);
  return { eye, f, r, u, focal, cx: x + w / 2, cy: y + h / 2 };
}
const NEAR = 0.05;
function toView(c, p) {
  const d = [p[0] - c.eye[0], p[1] - c.eye[1], p[2] - c.eye[2]];
  return [dot(d, c.r), dot(d, c.u), dot(d, c.f)];
}
const toScreen = (c, v) => [c.cx + (c.focal * v[0]) / v[2], c.cy - (c.focal * v[1]) / v[2]];

/* a world segment, clipped to the near plane; null when behind the camera */
function segment(c, a, b) {
  let va = toView(c, a), vb = toView(c, b);
  if (va[2] < NEAR && vb[2] < NEAR) return null;
  if (va[2] < NEAR || vb[2] < NEAR) {
    const s = (NEAR - va[2]) / (vb[2] - va[2]);
    const m = [va[0] + s * (vb[0] - va[0]), va[1] + s * (vb[1] - va[1]), NEAR];
    if (va[2] < NEAR) va = m; else vb = m;
  }
  return [toScreen(c, va), toScreen(c, vb)];
}

/* each motion's place on the floor now (its smoothed root): where the camera stays put */
function anchors() {
  return tracks.map((tr) => { const f = tr.frameAt(state.time); return [tr.smooth[f], tr.smooth[tr.T + f]]; });
}
/* what a panel looks at: the middle of its motions (side by side: each panel its own motion,
   wherever in the world it is, at the height of its own floor), following them or where they
   were when "follow" was unset; and how far the camera must back off to see them all (an
   overlay of motions apart on the floor or at other heights: 1 for one motion) */
function target(group, w, h) {
  const now = state.follow ? anchors() : cam.fixed;
  let x = 0, y = 0, low = Infinity, high = -Infinity;
  for (const tr of group) {
    x += now[tr.index][0]; y += now[tr.index][1];
    low = Math.min(low, tr.floor); high = Math.max(high, tr.floor);
  }
  x /= group.length; y /= group.length;
  let reach = 0;
  for (const tr of group) reach = Math.max(reach, Math.hypot(now[tr.index][0] - x, now[tr.index][1] - y));
  const t = Math.tan(cam.fov / 2), across = Math.max(t * (w / h), HALF_WIDTH / DIST0); // as camera() frames
  // a motion up to ``reach`` from the aim may stand that much nearer the camera
  const back = reach + Math.max((0.5 * (high - low) + 1.3) / t, (reach + HALF_WIDTH) / across);
  return [[x, y, 0.5 * (low + high) + UP], Math.max(1, back / DIST0)];
}

// ---------------------------------------------------------------- drawing the scene
function drawGrid(ctx, c, t, z) {
  const step = 0.5, reach = 6;
  const x0 = Math.round(t[0] / step) * step, y0 = Math.round(t[1] / step) * step;
  for (let i = -reach / step; i <= reach / step; i++) {
    const major = Math.abs(Math.round((x0 + i * step) / step)) % 2 === 0;
    for (const [a, b] of [[[x0 + i * step, y0 - reach, z], [x0 + i * step, y0 + reach, z]],
      [[x0 - reach, y0 + i * step, z], [x0 + reach, y0 + i * step, z]]]) {
      const s = segment(c, a, b);
      if (!s) continue;
      ctx.strokeStyle = major ? "rgba(0,0,0,0.16)" : "rgba(0,0,0,0.07)";
      ctx.beginPath(); ctx.moveTo(s[0][0], s[0][1]); ctx.lineTo(s[1][0], s[1][1]); ctx.stroke();
    }
  }
}

function drawContacts(ctx, c, tr, f, J) {
  for (let i = 0; i < FOOT.length; i++) {
    if (!tr.contact(f, i)) continue;
    const j = FOOT[i], pts = [];
    for (let k = 0; k < 14; k++) {
      const a = (k / 14) * 2 * Math.PI;
      const v = toView(c, [J[j * 3] + 0.07 * Math.cos(a), J[j * 3 + 1] + 0.07 * Math.sin(a), tr.floor]);
      if (v[2] < NEAR) { pts.length = 0; break; }
      pts.push(toScreen(c, v));
    }
    if (!pts.length) continue;
    ctx.fillStyle = rgba(tr.rgb, 0.45); ctx.strokeStyle = rgba(tr.rgb, 0.9);
    ctx.beginPath(); pts.forEach((p, k) => (k ? ctx.lineTo(p[0], p[1]) : ctx.moveTo(p[0], p[1])));
    ctx.closePath(); ctx.fill(); ctx.stroke();
  }
}

/* triangles of one track's skinned mesh, in view space, appended to tris */
function meshTriangles(c, tr, f, J, alpha, tris) {
  tr.pose(f);
  const mesh = meta.mesh, K = mesh.influences, R = tr.R, rv = tr.restVerts, RJ = tr.restJoints;
  const n = rv.length / 3, V = new Float64Array(n * 3);
  for (let v = 0; v < n; v++) {
    let x = 0, y = 0, z = 0;
    for (let k = 0; k < K; k++) {
      const j = meshJoints[v * K + k], w = meshWeights[v * K + k];
      if (!w) continue;
      const dx = rv[v * 3] - RJ[j * 3], dy = rv[v * 3 + 1] - RJ[j * 3 + 1], dz = rv[v * 3 + 2] - RJ[j * 3 + 2];
      const o = j * 9;
      x += w * (R[o] * dx + R[o + 1] * dy + R[o + 2] * dz + J[j * 3]);
      y += w * (R[o + 3] * dx + R[o + 4] * dy + R[o + 5] * dz + J[j * 3 + 1]);
      z += w * (R[o + 6] * dx + R[o + 7] * dy + R[o + 8] * dz + J[j * 3 + 2]);
    }
    const d = [x - c.eye[0], y - c.eye[1], z - c.eye[2]];
    V[v * 3] = dot(d, c.r); V[v * 3 + 1] = dot(d, c.u); V[v * 3 + 2] = dot(d, c.f);
  }
  const base = tr.rgb.map((ch) => ch + (255 - ch) * 0.3);
  for (let i = 0; i < meshFaces.length; i += 3) {
    const a = meshFaces[i] * 3, b = meshFaces[i + 1] * 3, d = meshFaces[i + 2] * 3;
    if (V[a + 2] < NEAR || V[b + 2] < NEAR || V[d + 2] < NEAR) continue;
    const e1 = [V[b] - V[a], V[b + 1] - V[a + 1], V[b + 2] - V[a + 2]];
    const e2 = [V[d] - V[a], V[d + 1] - V[a + 1], V[d + 2] - V[a + 2]];
    const nrm = norm(cross(e1, e2));
    const light = 0.35 + 0.65 * Math.abs(dot(nrm, [-0.35, 0.45, -0.82]));
    tris.push({
      depth: (V[a + 2] + V[b + 2] + V[d + 2]) / 3,
      p: [toScreen(c, [V[a], V[a + 1], V[a + 2]]), toScreen(c, [V[b], V[b + 1], V[b + 2]]),
        toScreen(c, [V[d], V[d + 1], V[d + 2]])],
      color: rgba(base.map((ch) => ch * light), alpha),
    });
  }
}

function drawSkeleton(ctx, c, tr, f, J, withMesh) {
  const P = (j) => [J[j * 3], J[j * 3 + 1], J[j * 3 + 2]];
  ctx.lineCap = "round";
  ctx.strokeStyle = withMesh ? "rgba(30,30,30,0.75)" : rgba(tr.rgb, 1);
  ctx.lineWidth = withMesh ? 1.6 : 3.2;
  for (let j = 1; j < NJ; j++) {
    const s = segment(c, P(PARENTS[j]), P(j));
    if (!s) continue;
    ctx.beginPath(); ctx.moveTo(s[0][0], s[0][1]); ctx.lineTo(s[1][0], s[1][1]); ctx.stroke();
  }
  for (let j = 0; j < NJ; j++) {
    const v = toView(c, P(j));
    if (v[2] < NEAR) continue;
    const p = toScreen(c, v), footIndex = FOOT.indexOf(j), planted = footIndex >= 0 && tr.contact(f, footIndex);
    ctx.fillStyle = planted ? "#fff" : withMesh ? "rgba(30,30,30,0.8)" : rgba(tr.rgb, 1);
    ctx.beginPath(); ctx.arc(p[0], p[1], planted ? 4.5 : withMesh ? 2 : 3, 0, 2 * Math.PI); ctx.fill();
    if (planted) { ctx.strokeStyle = rgba(tr.rgb, 1); ctx.lineWidth = 2.2; ctx.stroke(); ctx.lineWidth = withMesh ? 1.6 : 3.2; }
  }
}

function drawPanel(ctx, x, y, w, h, group, overlay) {
  ctx.save();
  ctx.beginPath(); ctx.rect(x, y, w, h); ctx.clip();
  const [t, fit] = target(group, w, h), c = camera(t, x, y, w, h, fit);
  view.panels.push({ target: t, distance: cam.dist * fit, focal: c.focal, motions: group.map((tr) => tr.index) });
  ctx.lineWidth = 1; drawGrid(ctx, c, t, Math.min(...group.map((tr) => tr.floor)));
  const showMesh = meta.mesh && state.body !== "skeleton";
  const showSkeleton = !meta.mesh || state.body !== "mesh";
  const posed = group.map((tr) => { const f = tr.frameAt(state.time); return [tr, f, Float64Array.from(tr.pose(f))]; });
  for (const [tr, f, J] of posed) drawContacts(ctx, c, tr, f, J);
  if (showMesh) {
    const tris = [];
    for (const [tr, f, J] of posed) meshTriangles(c, tr, f, J, overlay && group.length > 1 ? 0.55 : 1, tris);
    tris.sort((a, b) => b.depth - a.depth);
    ctx.lineWidth = 0.6; ctx.lineJoin = "round";
    for (const tri of tris) {
      ctx.fillStyle = tri.color; ctx.strokeStyle = tri.color;
      ctx.beginPath(); ctx.moveTo(tri.p[0][0], tri.p[0][1]); ctx.lineTo(tri.p[1][0], tri.p[1][1]);
      ctx.lineTo(tri.p[2][0], tri.p[2][1]); ctx.closePath(); ctx.fill(); ctx.stroke();
    }
  }
  if (showSkeleton) for (const [tr, f, J] of posed) drawSkeleton(ctx, c, tr, f, J, showMesh);
  ctx.font = "600 13px system-ui, sans-serif"; ctx.textBaseline = "top";
  let line = 0;
  posed.forEach(([tr, f]) => {
    const ended = state.time * tr.fps > tr.T - 0.5 ? "  (ended)" : "";
    const filled = tr.filledAt(f) ? `  (${tr.holeWord})` : "";
    const where = `frame ${f + 1}/${tr.T}${filled}${ended}`;
    ctx.fillStyle = tr.color;
    if (ctx.measureText(`${tr.name}  ${where}`).width <= w - 20) {
      ctx.fillText(`${tr.name}  ${where}`, x + 10, y + 8 + 18 * line++);
    } else { // a narrow panel: the name, then where it is, each on its own line
      ctx.fillText(tr.name, x + 10, y + 8 + 18 * line++);
      ctx.fillText(where, x + 10, y + 8 + 18 * line++);
    }
  });
  ctx.restore();
}

const scene = $("scene");
function render() {
  const dpr = window.devicePixelRatio || 1, W = scene.clientWidth, H = scene.clientHeight;
  if (scene.width !== Math.round(W * dpr) || scene.height !== Math.round(H * dpr)) {
    scene.width = Math.round(W * dpr); scene.height = Math.round(H * dpr);
  }
  const ctx = scene.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = "#fbfbf9"; ctx.fillRect(0, 0, W, H);
  view.panels = []; // each panel's camera as last drawn (for tests and the curious)
  if (state.layout === "overlay" || tracks.length === 1) drawPanel(ctx, 0, 0, W, H, tracks, true);
  else {
    const n = tracks.length, w = W / n;
    tracks.forEach((tr, i) => drawPanel(ctx, i * w, 0, w, H, [tr], false));
    ctx.strokeStyle = "#ddd"; ctx.lineWidth = 1;
    for (let i = 1; i < n; i++) { ctx.beginPath(); ctx.moveTo(i * w, 0); ctx.lineTo(i * w, H); ctx.stroke(); }
  }
  drawPlot();
  const frame = Math.round(state.time * state.fpsMax);
  $("timeline").value = String(frame);
  $("clock").textContent = `${state.time.toFixed(2)} / ${state.duration.toFixed(2)} s`;
  state.dirty = false;
}

