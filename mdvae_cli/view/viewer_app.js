/* mdvae view, part 4 of 4: controls, start-up and the test hook window.mdvaeView. */
// ---------------------------------------------------------------- controls
function setTime(t) {
  state.time = clamp(t, 0, state.duration);
  state.dirty = true;
}
function setPlaying(on) {
  state.playing = on && state.duration > 0;
  if (state.playing && state.time >= state.duration - 1e-9) state.time = 0;
  state.last = null;
  $("play").textContent = state.playing ? "pause" : "play";
}

function tick(now) {
  if (state.playing) {
    if (state.last !== null) {
      let t = state.time + ((now - state.last) / 1000) * state.speed;
      if (t > state.duration) {
        if (state.loop) t = state.duration > 0 ? t % state.duration : 0;
        else { t = state.duration; setPlaying(false); }
      }
      setTime(t);
    }
    state.last = now;
  }
  if (state.dirty) render();
  requestAnimationFrame(tick);
}

function setupControls() {
  $("title").textContent = meta.title;
  const legend = $("legend");
  for (const tr of tracks) {
    const li = document.createElement("li"), sw = document.createElement("span"), name = document.createElement("span"), info = document.createElement("span");
    sw.className = "swatch"; sw.style.background = tr.color;
    name.textContent = tr.name;
    const drawn = tr.holeWord === "missing" ? " in the file, drawn interpolated" : "";
    const filled = tr.filledFrames ? `, ${tr.filledFrames} ${tr.holeWord}${drawn} (shaded on the plot)` : "";
    info.className = "info"; info.textContent = `${tr.T} frame${tr.T === 1 ? "" : "s"}, ${+tr.fps.toFixed(3)} Hz${filled}`;
    li.append(sw, name, info); legend.append(li);
  }
  // the curves keep 150 px above a left and a right contact strip per motion
  plotCanvas.style.height = `${Math.max(230, 190 + 18 * tracks.length)}px`;
  const timeline = $("timeline");
  timeline.max = String(state.frames - 1);
  timeline.addEventListener("input", () => setTime(Number(timeline.value) / state.fpsMax));
  $("play").addEventListener("click", () => setPlaying(!state.playing));
  // a choice made, the keys play and step again (a select keeps the focus, and with it Space)
  const bind = (id, apply) => { const el = $(id); el.addEventListener("change", () => { apply(el); state.dirty = true; plotCache = null; if (el.tagName === "SELECT") el.blur(); }); };
  bind("speed", (el) => (state.speed = Number(el.value)));
  bind("layout", (el) => (state.layout = el.value));
  bind("body", (el) => (state.body = el.value));
  bind("follow", (el) => { state.follow = el.checked; cam.fixed = anchors(); });
  bind("loop", (el) => (state.loop = el.checked));
  if (!meta.mesh) { $("body").value = "skeleton"; $("body").disabled = true; state.body = "skeleton"; }
  const series = $("series"), joint = $("joint");
  for (const [k, [label]] of Object.entries(SERIES)) {
    series.add(new Option(label, k));
  }
  meta.joint_names.forEach((n, j) => joint.add(new Option(n.replace(/_/g, " "), String(j))));
  series.value = state.kind; joint.value = String(state.joint);
  bind("series", (el) => (state.kind = el.value));
  bind("joint", (el) => (state.joint = Number(el.value)));
  const windowSelect = $("window");
  if (state.duration > 30) state.window = 10; // a long take: 10 s around the cursor
  windowSelect.value = String(state.window);
  bind("window", (el) => (state.window = Number(el.value)));

  let drag = null;
  scene.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; scene.setPointerCapture(e.pointerId); });
  scene.addEventListener("pointermove", (e) => {
    if (!drag) return;
    cam.yaw -= (e.clientX - drag[0]) * 0.008;
    cam.pitch = clamp(cam.pitch + (e.clientY - drag[1]) * 0.006, -0.15, 1.45);
    drag = [e.clientX, e.clientY]; state.dirty = true;
  });
  scene.addEventListener("pointerup", () => (drag = null));
  scene.addEventListener("wheel", (e) => { e.preventDefault(); cam.dist = clamp(cam.dist * Math.exp(e.deltaY * 0.001), 1, 40); state.dirty = true; }, { passive: false });
  scene.addEventListener("dblclick", () => { cam.yaw = cam.home; cam.pitch = 0.28; cam.dist = 4.6; state.dirty = true; });
  window.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLSelectElement) return;
    if (e.key === " ") { e.preventDefault(); setPlaying(!state.playing); }
    else if (e.key === "ArrowRight" || e.key === "ArrowLeft") {
      e.preventDefault(); setPlaying(false);
      setTime(state.time + (e.key === "ArrowRight" ? 1 : -1) / state.fpsMax);
    } else if (e.key === "Home") setTime(0);
    else if (e.key === "End") setTime(state.duration);
  });
  window.addEventListener("resize", () => { state.dirty = true; });
  const rule = meta.contact_rule;
  $("help").textContent = "drag: orbit \u00b7 wheel: zoom \u00b7 double-click: reset the view \u00b7 " +
    "space: play / pause \u00b7 \u2190 \u2192: one frame. Feet in contact (an ankle or toe joint within " +
    `${rule.height_tol * 100} cm of its floor level and slower than ${rule.speed_max} m/s) are marked on ` +
    `the floor and in the strips under the plot (L, R per motion). Motions are aligned by time. ${meta.generator}.`;
}

/* the camera starts beside the first motion, looking at its side (the walking direction) */
function homeYaw() {
  const tr = tracks[0], T = tr.T, J = Float64Array.from(tr.pose(0));
  let fwd = [J[4] - J[7], -(J[3] - J[6]), 0]; // (left hip - right hip) x up: forward
  const dx = (tr.root[T - 1] - tr.root[0]) / POS, dy = (tr.root[2 * T - 1] - tr.root[T]) / POS;
  if (Math.hypot(dx, dy) > 1) fwd = [dx, dy, 0];
  return Math.atan2(fwd[1], fwd[0]) + (70 * Math.PI) / 180;
}

async function main() {
  try {
    tracks = await Promise.all(meta.motions.map(async (m, i) => {
      const arrays = {};
      for (const [key, d] of Object.entries(m.data)) arrays[key] = await decodeBlob(d);
      return new Track(m, arrays, i);
    }));
    if (meta.mesh) {
      meshFaces = Uint32Array.from(meta.mesh.faces);
      meshJoints = Uint8Array.from(meta.mesh.joints);
      meshWeights = Float64Array.from(meta.mesh.weights);
    }
  } catch (e) {
    const box = $("message"); box.hidden = false; box.textContent = `cannot show the motions: ${e.message}`;
    view.errors.push(String(e.message));
    return;
  }
  state.duration = Math.max(...tracks.map((tr) => (tr.T - 1) / tr.fps));
  state.fpsMax = Math.max(...tracks.map((tr) => tr.fps));
  state.frames = Math.round(state.duration * state.fpsMax) + 1;
  cam.yaw = cam.home = homeYaw();
  cam.fixed = anchors();
  view.decodedMs = performance.now();
  setupControls();
  render();
  view.firstFrameMs = performance.now();
  view.ready = true;
  requestAnimationFrame(tick);
}
let meshFaces = null, meshJoints = null, meshWeights = null;

Object.assign(view, {
  /* timeline frame (at the highest frame rate among the motions) -> draws it now */
  seek(frame) { setPlaying(false); setTime(frame / state.fpsMax); render(); return view.state(); },
  seekTime(seconds) { setPlaying(false); setTime(seconds); render(); return view.state(); },
  play() { setPlaying(true); }, pause() { setPlaying(false); },
  setLayout(v) { state.layout = v; $("layout").value = v; render(); },
  setBody(v) { state.body = meta.mesh ? v : "skeleton"; $("body").value = state.body; render(); },
  setPlot(kind, joint, seconds) {
    if (!SERIES[kind] || !(joint >= 0 && joint < NJ)) throw new Error(`no series ${kind} of joint ${joint}`);
    state.kind = kind; state.joint = joint; plotCache = null;
    $("series").value = kind; $("joint").value = String(joint);
    if (seconds !== undefined) { state.window = seconds; $("window").value = String(seconds); }
    render();
  },
  render() { render(); },
  /* motion i's joints at its own frame f: [x0, y0, z0, x1, ...] metres (forward kinematics) */
  jointsAt(i, f) { return Array.from(tracks[i].pose(f)); },
  state() {
    return {
      time: state.time, frame: Math.round(state.time * state.fpsMax), frames: state.frames,
      fps: state.fpsMax, duration: state.duration, playing: state.playing, layout: state.layout,
      body: state.body, mesh: !!meta.mesh, motions: tracks.map((tr) => ({ name: tr.name, frame: tr.frameAt(state.time), frames: tr.T, filled: tr.filledAt(tr.frameAt(state.time)) })),
    };
  },
});
main();
