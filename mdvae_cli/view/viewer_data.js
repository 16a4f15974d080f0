/* mdvae view, part 1 of 4: the page's data (decoding, one motion's forward kinematics and
 * series). The parts share one scope: mdvae_cli/view/page.py joins them in one function. */
const view = (window.mdvaeView = { ready: false, errors: [], firstFrameMs: null, decodedMs: null });
window.addEventListener("error", (e) => view.errors.push(String(e.message || e)));
window.addEventListener("unhandledrejection", (e) => view.errors.push(String(e.reason)));

const $ = (id) => document.getElementById(id);
const meta = JSON.parse($("mdvae-meta").textContent);
const NJ = meta.joint_names.length;
const PARENTS = meta.parents;
const FOOT = meta.foot_joints;
const UP = 0.9; // camera aim above the floor, metres
const SERIES = {
  rotation: ["joint angle", "\u00b0"], bend: ["bend angle", "\u00b0"],
  height: ["height", " m"], speed: ["speed", " m/s"],
};

// ---------------------------------------------------------------- decoding
const SIZES = { Int8: 1, Uint8: 1, Int16: 2, Int32: 4 };
const ARRAYS = { Int8: Int8Array, Uint8: Uint8Array, Int16: Int16Array, Int32: Int32Array };

function base64Bytes(text) {
  if (typeof Uint8Array.fromBase64 === "function") return Uint8Array.fromBase64(text.trim());
  const bin = atob(text.trim());
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out;
}

async function inflate(bytes) {
  if (typeof DecompressionStream === "undefined") {
    throw new Error("this browser cannot decompress the data (no DecompressionStream): " +
      "open the page in a current Chrome, Edge, Firefox or Safari");
  }
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

/* -> typed array laid out channel by channel: value(t, c) = arr[c * frames + t].
 * One pass per channel undoes the byte shuffle (byte k of item i is packed[k * n + i]) and
 * the time differences, in the type's own wrap-around arithmetic. */
async function decodeBlob(d) {
  const element = $(d.id);
  const packed = await inflate(base64Bytes(element.textContent));
  element.remove(); // the text is no longer needed
  const T = d.frames, n = T * d.channels, size = SIZES[d.type];
  if (packed.length !== n * size) throw new Error(`${d.id}: ${packed.length} bytes, expected ${n * size}`);
  const out = new ARRAYS[d.type](n);
  if (d.type === "Int16") unpack16(packed, out, T, d.channels, d.delta);
  else if (d.type === "Int32") unpack32(packed, out, T, d.channels, d.delta);
  else unpack8(packed, out, T, d.channels, d.delta);
  return out;
}
/* byte planes -> integers: an array of differences (d.delta = 1 or 2) is zigzagged (0, 1, 2, 3
   for 0, -1, 1, -2) and summed d.delta times; sums wrap at the array's width, as encoded */
function unpack8(p, out, T, C, order) {
  for (let c = 0, i = 0; c < C; c++) {
    let acc = 0, vel = 0;
    for (let t = 0; t < T; t++, i++) {
      const v = order ? (p[i] >>> 1) ^ -(p[i] & 1) : p[i];
      if (order === 2) { vel = (vel + v) | 0; acc = (acc + vel) | 0; } else acc = order ? (acc + v) | 0 : v;
      out[i] = acc; // the typed array wraps to its 8 bits
    }
  }
}
function unpack16(p, out, T, C, order) {
  const n = T * C;
  for (let c = 0, i = 0; c < C; c++) {
    let acc = 0, vel = 0;
    for (let t = 0; t < T; t++, i++) {
      const u = p[i] | (p[n + i] << 8);
      const v = order ? (u >>> 1) ^ -(u & 1) : (u << 16) >> 16;
      if (order === 2) { vel = ((vel + v) << 16) >> 16; acc = ((acc + vel) << 16) >> 16; }
      else acc = order ? ((acc + v) << 16) >> 16 : v;
      out[i] = acc;
    }
  }
}
function unpack32(p, out, T, C, order) {
  const n = T * C;
  for (let c = 0, i = 0; c < C; c++) {
    let acc = 0, vel = 0;
    for (let t = 0; t < T; t++, i++) {
      const u = p[i] | (p[n + i] << 8) | (p[2 * n + i] << 16) | (p[3 * n + i] << 24);
      const v = order ? (u >>> 1) ^ -(u & 1) : u;
      if (order === 2) { vel = (vel + v) | 0; acc = (acc + vel) | 0; } else acc = order ? (acc + v) | 0 : v;
      out[i] = acc;
    }
  }
}

// ---------------------------------------------------------------- small maths
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };
const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));

function hexRgb(hex) {
  const v = parseInt(hex.slice(1), 16);
  return [(v >> 16) & 255, (v >> 8) & 255, v & 255];
}
const rgba = (c, a) => `rgba(${c[0] | 0},${c[1] | 0},${c[2] | 0},${a})`;

/* quaternion (w, x, y, z) -> row-major 3x3 into out[o..o+8] */
function quatMatrix(w, x, y, z, out, o) {
  const l = Math.sqrt(w * w + x * x + y * y + z * z) || 1;
  w /= l; x /= l; y /= l; z /= l;
  out[o] = 1 - 2 * (y * y + z * z); out[o + 1] = 2 * (x * y - w * z); out[o + 2] = 2 * (x * z + w * y);
  out[o + 3] = 2 * (x * y + w * z); out[o + 4] = 1 - 2 * (x * x + z * z); out[o + 5] = 2 * (y * z - w * x);
  out[o + 6] = 2 * (x * z - w * y); out[o + 7] = 2 * (y * z + w * x); out[o + 8] = 1 - 2 * (x * x + y * y);
}

// ---------------------------------------------------------------- one motion
const POS = meta.scales.position, ROT = meta.scales.rotation, SCRATCH = new Float64Array(9);
class Track {
  constructor(m, arrays, index) {
    this.index = index; this.name = m.name; this.color = m.color; this.rgb = hexRgb(m.color);
    this.fps = m.fps; this.T = m.frames;
    this.floor = m.floor ?? meta.floor; // its own floor: where its planted feet are marked
    this.root = arrays.root; this.rot = arrays.rot; this.contacts = arrays.contacts;
    // each rotation channel's integer units (a noisy channel's are coarser; older pages: one)
    this.rotScales = Float64Array.from(m.rotation_scales || new Array(4 + (NJ - 1) * 3).fill(ROT));
    this.restJoints = Float64Array.from(m.rest_joints);
    this.restVerts = m.rest_vertices ? Float64Array.from(m.rest_vertices) : null;
    this.J = new Float64Array(NJ * 3); // the posed frame: joint positions (metres)
    this.R = new Float64Array(NJ * 9); // and world rotations (row-major 3x3)
    this.posedFrame = -1;
    this.series = {};
    this.smooth = this.smoothRoot(0.5);
    this.filled = m.filled || []; // [start, stop) runs of frames with a joint missing in the file
    this.filledFrames = this.filled.reduce((n, r) => n + r[1] - r[0], 0);
    // holes the file itself lacks (NaN rows) are drawn interpolated; a result's were filled
    this.holeWord = m.missing_in_file ? "missing" : "filled";
  }
  filledAt(f) { return this.filled.some((r) => f >= r[0] && f < r[1]); }
  frameAt(time) { return clamp(Math.round(time * this.fps), 0, this.T - 1); }
  /* forward kinematics of frame f: fills this.J and this.R (as the body model poses) */
  pose(f) {
    if (f === this.posedFrame) return this.J;
    const T = this.T, q = this.rot, J = this.J, R = this.R, RJ = this.restJoints, L = SCRATCH;
    const s = this.rotScales;
    quatMatrix(q[f] / s[0], q[T + f] / s[1], q[2 * T + f] / s[2], q[3 * T + f] / s[3], R, 0);
    for (let k = 0; k < 3; k++) J[k] = this.root[k * T + f] / POS;
    for (let j = 1; j < NJ; j++) {
      const c = 4 + (j - 1) * 3, x = q[c * T + f] / s[c], y = q[(c + 1) * T + f] / s[c + 1], z = q[(c + 2) * T + f] / s[c + 2];
      quatMatrix(Math.sqrt(Math.max(0, 1 - x * x - y * y - z * z)), x, y, z, L, 0);
      const p = PARENTS[j], o = j * 9, po = p * 9;
      for (let r = 0; r < 3; r++) {
        for (let col = 0; col < 3; col++) {
          R[o + r * 3 + col] = R[po + r * 3] * L[col] + R[po + r * 3 + 1] * L[3 + col] + R[po + r * 3 + 2] * L[6 + col];
        }
      }
      const dx = RJ[j * 3] - RJ[p * 3], dy = RJ[j * 3 + 1] - RJ[p * 3 + 1], dz = RJ[j * 3 + 2] - RJ[p * 3 + 2];
      J[j * 3] = J[p * 3] + R[po] * dx + R[po + 1] * dy + R[po + 2] * dz;
      J[j * 3 + 1] = J[p * 3 + 1] + R[po + 3] * dx + R[po + 4] * dy + R[po + 5] * dz;
      J[j * 3 + 2] = J[p * 3 + 2] + R[po + 6] * dx + R[po + 7] * dy + R[po + 8] * dz;
    }
    this.posedFrame = f;
    return J;
  }
  /* the rotation angle of joint j relative to its parent (the root: in the world), degrees */
  rotationAngle(f, j) {
    const T = this.T, q = this.rot, s = this.rotScales;
    let w;
    if (j === 0) {
      const a = q[f] / s[0], x = q[T + f] / s[1], y = q[2 * T + f] / s[2], z = q[3 * T + f] / s[3];
      w = Math.abs(a) / (Math.sqrt(a * a + x * x + y * y + z * z) || 1);
    } else {
      const c = 4 + (j - 1) * 3, x = q[c * T + f] / s[c], y = q[(c + 1) * T + f] / s[c + 1], z = q[(c + 2) * T + f] / s[c + 2];
      w = Math.sqrt(Math.max(0, 1 - x * x - y * y - z * z));
    }
    return (2 * Math.acos(Math.min(1, w)) * 180) / Math.PI;
  }
  contact(f, i) { return (this.contacts[f] >> i) & 1; }
  /* root x, y averaged over +-halfWindow seconds (a camera that follows without shaking) */
  smoothRoot(halfWindow) {
    const T = this.T, k = Math.max(0, Math.round(halfWindow * this.fps));
    const out = new Float64Array(2 * T);
    for (let axis = 0; axis < 2; axis++) {
      const pre = new Float64Array(T + 1);
      for (let t = 0; t < T; t++) pre[t + 1] = pre[t] + this.root[axis * T + t] / POS;
      for (let t = 0; t < T; t++) {
        const a = Math.max(0, t - k), b = Math.min(T, t + k + 1);
        out[axis * T + t] = (pre[b] - pre[a]) / (b - a);
      }
    }
    return out;
  }
  /* one series over all frames (Float64Array, NaN where undefined) */
  seriesOf(kind, j) {
    const key = kind + j;
    if (this.series[key]) return this.series[key];
    const T = this.T, out = new Float64Array(T).fill(NaN), child = meta.bend_child[String(j)];
    if (kind === "rotation") for (let f = 0; f < T; f++) out[f] = this.rotationAngle(f, j);
    else if (kind === "height") for (let f = 0; f < T; f++) out[f] = this.pose(f)[j * 3 + 2];
    else if (kind === "bend" && child !== undefined) {
      const p = PARENTS[j];
      for (let f = 0; f < T; f++) {
        const P = this.pose(f);
        const a0 = P[j * 3] - P[p * 3], a1 = P[j * 3 + 1] - P[p * 3 + 1], a2 = P[j * 3 + 2] - P[p * 3 + 2];
        const b0 = P[child * 3] - P[j * 3], b1 = P[child * 3 + 1] - P[j * 3 + 1], b2 = P[child * 3 + 2] - P[j * 3 + 2];
        const c = (a0 * b0 + a1 * b1 + a2 * b2) / Math.max(Math.sqrt((a0 * a0 + a1 * a1 + a2 * a2) * (b0 * b0 + b1 * b1 + b2 * b2)), 1e-12);
        out[f] = (Math.acos(clamp(c, -1, 1)) * 180) / Math.PI;
      }
    } else if (kind === "speed") { // central differences, one-sided at the ends
      const pos = new Float64Array(T * 3);
      for (let f = 0; f < T; f++) { const P = this.pose(f); pos.set(P.subarray(j * 3, j * 3 + 3), f * 3); }
      for (let f = 0; f < T; f++) {
        const a = Math.max(0, f - 1), b = Math.min(T - 1, f + 1);
        out[f] = b > a ? Math.hypot(pos[b * 3] - pos[a * 3], pos[b * 3 + 1] - pos[a * 3 + 1], pos[b * 3 + 2] - pos[a * 3 + 2]) / ((b - a) / this.fps) : 0;
      }
    }
    this.series[key] = out;
    return out;
  }
}

