/* mdvae view, part 3 of 4: the plot under the scene (decimated to the pixels drawn). */
// ---------------------------------------------------------------- the plot
const plotCanvas = $("plot");
function niceStep(span, count) {
  const raw = span / Math.max(count, 1), p = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
  return 10 * p;
}

function plotLayout(W, H) {
  const strip = 9, rows = tracks.length * 2;
  const bottom = 22 + rows * strip + 8;
  return { left: 58, right: 12, top: 10, bottom, strip, W, H, ph: H - 10 - bottom, pw: W - 70 };
}

/* the chosen series of every motion and its value range (padded), cached per choice */
let rangeCache = null;
function plotRange() {
  const key = state.kind + state.joint;
  if (rangeCache && rangeCache.key === key) return rangeCache;
  const series = tracks.map((tr) => tr.seriesOf(state.kind, state.joint));
  let lo = Infinity, hi = -Infinity;
  for (const s of series) for (let f = 0; f < s.length; f++) if (Number.isFinite(s[f])) { lo = Math.min(lo, s[f]); hi = Math.max(hi, s[f]); }
  const ok = Number.isFinite(lo);
  if (!ok) { lo = 0; hi = 1; }
  if (hi - lo < 1e-6) { hi += 0.5; lo -= 0.5; }
  const pad = 0.06 * (hi - lo);
  rangeCache = { key, series, ok, lo: lo - pad, hi: hi + pad };
  return rangeCache;
}

/* axes, curves and contact strips of the time span [t0, t1] */
function drawPlotBody(ctx, L, t0, t1) {
  const range = plotRange(), { lo, hi } = range, span = Math.max(t1 - t0, 1e-9);
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, L.W, L.H);
  const X = (t) => L.left + ((t - t0) / span) * L.pw;
  const Y = (v) => L.top + (1 - (v - lo) / (hi - lo)) * L.ph;
  const label = `${meta.joint_names[state.joint].replace(/_/g, " ")} ${SERIES[state.kind][0]}`;
  ctx.font = "12px system-ui, sans-serif"; ctx.fillStyle = "#555"; ctx.textBaseline = "middle";
  ctx.strokeStyle = "#eee"; ctx.lineWidth = 1; ctx.textAlign = "right";
  if (!range.ok) {
    ctx.textAlign = "left";
    const why = state.joint === 0 ? "no bone into it" : "no bone out of it";
    ctx.fillText(`no ${label}: the ${meta.joint_names[state.joint]} has ${why}`, L.left + 10, L.top + L.ph / 2);
  } else {
    const ys = niceStep(hi - lo, 5);
    for (let v = Math.ceil(lo / ys) * ys; v <= hi; v += ys) {
      ctx.beginPath(); ctx.moveTo(L.left, Y(v)); ctx.lineTo(L.left + L.pw, Y(v)); ctx.stroke();
      ctx.fillText(`${+v.toFixed(3)}`, L.left - 6, Y(v));
    }
    ctx.save(); ctx.translate(12, L.top + L.ph / 2); ctx.rotate(-Math.PI / 2); ctx.textAlign = "center";
    ctx.fillText(`${label} (${SERIES[state.kind][1].trim()})`, 0, 0); ctx.restore();
  }
  const xs = niceStep(Math.max(span, 1e-3), Math.max(2, Math.floor(L.pw / 110))); // one frame: one tick
  ctx.textBaseline = "top";
  for (let t = Math.ceil(t0 / xs) * xs; t <= t1 + 1e-9; t += xs) {
    ctx.beginPath(); ctx.moveTo(X(t), L.top); ctx.lineTo(X(t), L.top + L.ph); ctx.stroke();
    ctx.textAlign = X(t) > L.left + L.pw - 30 ? "right" : X(t) < L.left + 30 ? "left" : "center";
    ctx.fillText(`${+t.toFixed(2)} s`, X(t), L.top + L.ph + 4);
  }
  ctx.save(); ctx.beginPath(); ctx.rect(L.left, L.top, L.pw, L.ph); ctx.clip();
  // frames filled (missing in the file): a band in the motion's colour, a bar along the top
  tracks.forEach((tr, i) => {
    for (const [a, b] of tr.filled) {
      const x0 = X((a - 0.5) / tr.fps), x1 = X((b - 0.5) / tr.fps), w = Math.max(1, x1 - x0);
      ctx.fillStyle = tr.color; ctx.globalAlpha = 0.12; ctx.fillRect(x0, L.top, w, L.ph);
      ctx.globalAlpha = 1; ctx.fillRect(x0, L.top + 4 * i, w, 4);
    }
  });
  tracks.forEach((tr, i) => {
    if (!range.ok) return;
    const s = range.series[i], T = tr.T;
    const a0 = clamp(Math.floor(t0 * tr.fps) - 1, 0, T - 1), a1 = clamp(Math.ceil(t1 * tr.fps) + 1, 0, T - 1);
    const count = a1 - a0 + 1;
    if (count <= 2 * L.pw) { // few frames: every frame
      ctx.strokeStyle = tr.color; ctx.lineWidth = 1.4; ctx.beginPath();
      let pen = false;
      for (let f = a0; f <= a1; f++) {
        if (!Number.isFinite(s[f])) { pen = false; continue; }
        const x = X(f / tr.fps), y = Y(s[f]);
        if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y);
        pen = true;
      }
      ctx.stroke();
    } else { // many frames: the min-max envelope of each pixel column (decimated drawing)
      ctx.fillStyle = tr.color;
      const cols = Math.ceil(L.pw);
      for (let px = 0; px < cols; px++) { // columns share their edge frame: no gaps
        const a = a0 + Math.floor((px / cols) * count), b = Math.min(a1, a0 + Math.floor(((px + 1) / cols) * count));
        let mn = Infinity, mx = -Infinity;
        for (let f = a; f <= b; f++) if (Number.isFinite(s[f])) { mn = Math.min(mn, s[f]); mx = Math.max(mx, s[f]); }
        if (Number.isFinite(mn)) ctx.fillRect(X(a / tr.fps) - 0.7, Y(mx) - 0.7, 1.4, Y(mn) - Y(mx) + 1.4);
      }
    }
  });
  ctx.restore();
  // foot contact strips: per motion, left foot then right foot (ankle or toe joint planted)
  const top = L.top + L.ph + 22;
  ctx.textAlign = "right"; ctx.textBaseline = "middle"; ctx.font = "8px system-ui, sans-serif";
  tracks.forEach((tr, i) => {
    const a0 = clamp(Math.floor(t0 * tr.fps), 0, tr.T - 1), a1 = clamp(Math.ceil(t1 * tr.fps), 0, tr.T - 1);
    for (let side = 0; side < 2; side++) {
      const y = top + (i * 2 + side) * L.strip;
      ctx.fillStyle = "#f1f1ee"; ctx.fillRect(L.left, y, L.pw, L.strip - 1);
      ctx.fillStyle = tr.color;
      let start = -1; // one rectangle per run of frames in contact
      for (let f = a0; f <= a1 + 1; f++) {
        const on = f <= a1 && (tr.contact(f, side) || tr.contact(f, side + 2));
        if (on && start < 0) start = f;
        else if (!on && start >= 0) {
          const x0 = Math.max(L.left, X(start / tr.fps)), x1 = Math.min(L.left + L.pw, X(f / tr.fps));
          if (x1 > x0) ctx.fillRect(x0, y, Math.max(1, x1 - x0), L.strip - 1);
          start = -1;
        }
      }
      ctx.fillStyle = "#777"; ctx.fillText(side ? "R" : "L", L.left - 4, y + L.strip / 2);
    }
  });
}

/* the whole take is drawn once and kept; a window around the cursor is drawn every frame */
function drawPlot() {
  const dpr = window.devicePixelRatio || 1, W = plotCanvas.clientWidth, H = plotCanvas.clientHeight;
  if (plotCanvas.width !== Math.round(W * dpr) || plotCanvas.height !== Math.round(H * dpr)) {
    plotCanvas.width = Math.round(W * dpr); plotCanvas.height = Math.round(H * dpr);
  }
  const ctx = plotCanvas.getContext("2d"), L = plotLayout(W, H);
  let t0 = 0, t1 = state.duration;
  if (state.window > 0 && state.window < state.duration) {
    t0 = clamp(state.time - state.window / 2, 0, state.duration - state.window);
    t1 = t0 + state.window;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    drawPlotBody(ctx, L, t0, t1);
  } else {
    const key = [W, H, dpr, state.kind, state.joint].join();
    if (!plotCache || plotCache.key !== key) {
      const canvas = document.createElement("canvas");
      canvas.width = plotCanvas.width; canvas.height = plotCanvas.height;
      const cc = canvas.getContext("2d");
      cc.setTransform(dpr, 0, 0, dpr, 0, 0);
      drawPlotBody(cc, L, t0, t1);
      plotCache = { key, canvas };
    }
    ctx.setTransform(1, 0, 0, 1, 0, 0); ctx.drawImage(plotCache.canvas, 0, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  }
  const range = plotRange(), span = Math.max(t1 - t0, 1e-9);
  const X = (t) => L.left + ((t - t0) / span) * L.pw;
  ctx.strokeStyle = "rgba(0,0,0,0.55)"; ctx.lineWidth = 1;
  ctx.beginPath(); ctx.moveTo(X(state.time), L.top); ctx.lineTo(X(state.time), L.H - 4); ctx.stroke();
  const parts = [];
  tracks.forEach((tr, i) => {
    const f = tr.frameAt(state.time), v = range.series[i][f];
    if (!range.ok || !Number.isFinite(v)) return;
    const y = L.top + (1 - (v - range.lo) / (range.hi - range.lo)) * L.ph;
    ctx.fillStyle = tr.color; ctx.beginPath(); ctx.arc(X(f / tr.fps), y, 3.5, 0, 2 * Math.PI); ctx.fill();
    const filled = tr.filledAt(f) ? " (filled)" : "";
    parts.push(`${tr.name} ${v.toFixed(state.kind === "height" ? 3 : 1)}${SERIES[state.kind][1]}${filled}`);
  });
  $("readout").textContent = parts.join("   ");
}

