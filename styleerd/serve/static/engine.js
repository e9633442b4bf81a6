// The styleerd step in the browser: onnxruntime-web (vendored from npm, no CDN) runs the
// exported LSTM-op graph; StyleHost computes each frame's features from a pose on the model's
// skeleton, as examples/onnx_host.py and docs/ONNX.md describe, and keeps the stream's state.
// A web avatar app retargets its avatar to the model's skeleton and calls host.step(pose).
// Each frame runs the graph twice, each run with its own state: into the target and into the
// input's own style (the identity transfer). Where the identity output is near the input the
// output is the network's; where it is far (an action the network never learnt) the input's pose
// turned by the target style's posture (the sidecar's rotation vectors), then so that its joints go where the
// posture moves the input's (posture_offsets); in between a blend: as the server.
import * as ort from "/static/vendor/ort.wasm.min.mjs";

ort.env.wasm.wasmPaths = "/static/vendor/";
ort.env.wasm.numThreads = 1; // no cross-origin isolation needed, and one frame is small work

const qmul = (a, b) => [
  a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
  a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
  a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
  a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
function qrot(q, v) { // v + w t + u x t, t = 2 u x v
  const u = [q[1], q[2], q[3]], t = cross(u, v).map((x) => 2 * x), ut = cross(u, t);
  return [0, 1, 2].map((k) => v[k] + q[0] * t[k] + ut[k]);
}
const normalize = (q) => { const n = Math.hypot(...q) || 1; return q.map((x) => x / n); };
const inverse = (q) => [q[0], -q[1], -q[2], -q[3]];
const [FAMILIAR, UNFAMILIAR] = [10.0, 16.0]; // degrees: styleerd.model.config's, where the export has no familiar_degrees
const [RISE, RELEASE] = [0.25, 0.1]; // a frame: the same, where it has no unfamiliar_rise_release
function slerp(a, b, t) { // from a (t = 0) to b (t = 1) along the shorter arc
  let d = a.reduce((s, x, k) => s + x * b[k], 0);
  if (d < 0) { b = b.map((x) => -x); d = -d; }
  const theta = Math.acos(Math.min(1, d)), s = Math.sin(theta);
  const [wa, wb] = s < 1e-6 ? [1 - t, t] : [Math.sin((1 - t) * theta) / s, Math.sin(t * theta) / s];
  return normalize(a.map((x, k) => wa * x + wb * b[k]));
}

function shortestArc(a, b) { // the rotation by the smallest angle taking a's direction to b's (a zero vector: none)
  const na = Math.hypot(...a), nb = Math.hypot(...b);
  if (na < 1e-12 || nb < 1e-12) return [1, 0, 0, 0];
  a = a.map((x) => x / na); b = b.map((x) => x / nb);
  const w = 1 + a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  if (w < 1e-9) return normalize([0, ...cross(a, Math.abs(a[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0])]); // opposite: a half turn
  return normalize([w, ...cross(a, b)]);
}
// The pose rot turned so that each joint's children go towards targets (global): down the chain, each joint but
// the root by the shortest arc from its children's summed bone vectors to the summed vectors to their targets.
// given: the input's global joint positions (the root's is kept); as examples/onnx_host.py's reach.
// The frames a posture's offsets are in, as rows (left, up, forward; motion.kinematics' heading_axes, body_axes).
function headingAxes(heading) { return [[1, 0, 0], [0, 1, 0], [0, 0, 1]].map((v) => qrot(heading, v)); }
function bodyAxes(g, roles) { // up from the hips to the head, left from the right hip and shoulder to the left ones
  const up = [0, 1, 2].map((k) => g[roles.head][k] - g[roles.hips][k]);
  const across = [0, 1, 2].map((k) => g[roles.left[0]][k] + g[roles.left[1]][k] - g[roles.right[0]][k] - g[roles.right[1]][k]);
  const forward = cross(across, up);
  return [cross(up, forward), up, forward].map((v) => { const n = Math.max(Math.hypot(...v), 1e-9); return v.map((x) => x / n); });
}

// Where a two-bone limb's middle joint goes, from the limb's first joint, given its target elbow and the end's target
// end (both from the first joint): the point at upper from the first joint nearest, in the least squares, to its
// target and to the sphere of radius lower about the end's, by rounds rounds of projections (onnx_host's limb_elbow).
function limbElbow(elbow, end, upper, lower, rounds) {
  let e = elbow;
  const onto = (v, length) => { const n = Math.max(Math.hypot(...v), 1e-12); return v.map((x) => (length * x) / n); };
  for (let r = 0; r < rounds; r++) {
    e = onto(e, upper);
    const toEnd = onto(e.map((x, k) => x - end[k]), lower);
    e = e.map((_, k) => 0.5 * (elbow[k] + end[k] + toEnd[k]));
  }
  return onto(e, upper);
}

// limbEnds[j]: for the first joint of a two-bone limb its end (turned towards limbElbow's place), else -1.
function reach(rot, pos, given, targets, parents, limbEnds, rounds) {
  rot = rot.slice();
  const gRot = rot.slice(), gPos = given.slice();
  parents.forEach((p, j) => {
    if (p < 0) return;
    gRot[j] = qmul(gRot[p], rot[j]);
    gPos[j] = qrot(gRot[p], pos[j]).map((x, k) => x + gPos[p][k]);
    const now = [0, 0, 0];
    let wanted = [0, 0, 0], kids = 0;
    for (let k = j + 1; k < parents.length; k++) {
      if (parents[k] !== j) continue;
      kids++;
      const v = qrot(gRot[j], pos[k]);
      for (let i = 0; i < 3; i++) { now[i] += v[i]; wanted[i] += targets[k][i] - gPos[j][i]; }
    }
    if (!kids) return;
    const end = limbEnds[j];
    if (end >= 0) {
      const toEnd = targets[end].map((x, i) => x - gPos[j][i]);
      wanted = limbElbow(wanted, toEnd, Math.hypot(...now), Math.hypot(...pos[end]), rounds);
    }
    gRot[j] = qmul(shortestArc(now, wanted), gRot[j]);
    rot[j] = qmul(inverse(gRot[p]), gRot[j]);
  });
  return rot;
}

export class StyleHost {
  static async create(base = "/onnx/stylizer") {
    const side = await (await fetch(`${base}.json`)).json();
    const session = await ort.InferenceSession.create(`${base}.onnx`, { executionProviders: ["wasm"] });
    return new StyleHost(side, session);
  }

  constructor(side, session) {
    this.side = side;
    this.session = session;
    this.parents = side.skeleton.parents;
    this.mean = side.stats.mean; this.std = side.stats.std; this.reference = side.stats.reference;
    this.roles = side.roles;
    this.maxFootSpeed = side.contact_speed_leg_lengths * side.roles.leg_length;
    [this.S, , this.H] = side.state_shapes.h; // [1, N, S H] (LSTM form) or [S, N, H] (plain)
    this.setLabels("normal", "walk", { elderly: 1 });
    this.reset();
  }

  oneHot(names, weights) {
    const v = new Float32Array(names.length);
    for (const [name, w] of Object.entries(weights)) {
      if (!names.includes(name)) throw new Error(`unknown label ${name}; valid: ${names.join(", ")}`);
      v[names.indexOf(name)] = w;
    }
    return v;
  }

  setLabels(inputStyle, content, target) {
    this.style = this.oneHot(this.side.input_styles || this.side.styles, { [inputStyle]: 1 });
    this.content = this.oneHot(this.side.contents, { [content]: 1 });
    this.target = this.oneHot(this.side.styles, target);
    this.identity = new Float32Array(this.side.styles.length);
    this.identity.set(this.style); // the input's own style, among the targets
    // the target style's posture change from the input's own (rotation vectors summed by weight); null: none measured
    const posture = this.side.posture;
    this.change = posture && posture[0].map((joint, j) => {
      const v = [0, 1, 2].map((k) => posture.reduce((sum, style, s) => sum + (this.target[s] - this.identity[s]) * style[j][k], 0));
      const angle = Math.hypot(...v), scale = angle > 1e-12 ? Math.sin(angle / 2) / angle : 0.5;
      return [Math.cos(angle / 2), ...v.map((x) => x * scale)];
    });
    // where the posture moves each joint (in the frame side.posture_frame names), summed by weight; null: none measured
    const offsets = this.side.posture_offsets;
    this.moved = offsets && offsets[0].map((joint, j) =>
      [0, 1, 2].map((k) => offsets.reduce((sum, style, s) => sum + (this.target[s] - this.identity[s]) * style[j][k], 0)));
  }

  reset() {
    const zeros = () => ({ h: new Float32Array(this.S * this.H), c: new Float32Array(this.S * this.H) });
    this.state = { target: zeros(), identity: zeros() };
    this.unfamiliar = 0; // 0: the network's pose, 1: the input's pose turned by the style's change
    this.previous = null;
    this.facing = [0, 0, 1];
  }

  features(rot, pos, fps) { // rot: J quaternions [w, x, y, z]; pos: J local translations
    const J = this.parents.length;
    rot = rot.map(normalize);
    const gRot = [], g = [];
    for (let j = 0; j < J; j++) {
      const p = this.parents[j];
      if (p < 0) { gRot.push(rot[j]); g.push(pos[j]); } else { gRot.push(qmul(gRot[p], rot[j])); g.push(qrot(gRot[p], pos[j]).map((x, k) => x + g[p][k])); }
    }
    const { left, right, feet } = this.roles;
    const a = [0, 1, 2].map((k) => g[left[0]][k] + g[left[1]][k] - g[right[0]][k] - g[right[1]][k]);
    const fx = -a[2], fz = a[0], fn = Math.hypot(fx, fz);
    if (fn > 1e-6 * Math.max(1, Math.hypot(...a))) this.facing = [fx / fn, 0, fz / fn];
    const half = Math.atan2(this.facing[0], this.facing[2]) / 2;
    const heading = [Math.cos(half), 0, Math.sin(half), 0], inverse = [heading[0], 0, -heading[2], 0];
    const x = new Float32Array(10 * J + 4);
    const put = (d, value) => { x[d] = (value - this.mean[d]) / this.std[d]; };
    for (let j = 0; j < J; j++) {
      let q = j === 0 ? qmul(inverse, rot[0]) : rot[j];
      if (q[0] < 0) q = q.map((v) => -v);
      const r = this.reference[j];
      if (q[0] * r[0] + q[1] * r[1] + q[2] * r[2] + q[3] * r[3] < 0) q = q.map((v) => -v);
      q.forEach((v, k) => put(4 * j + k, v));
    }
    const previous = this.previous || g;
    for (let j = 0; j < J; j++) {
      qrot(inverse, [0, 1, 2].map((k) => g[j][k] - g[0][k])).forEach((v, k) => put(4 * J + 3 * j + k, v));
      qrot(inverse, [0, 1, 2].map((k) => (g[j][k] - previous[j][k]) * fps)).forEach((v, k) => put(7 * J + 3 * j + k, v));
    }
    feet.forEach((f, k) => put(10 * J + k, Math.hypot(...[0, 1, 2].map((i) => g[f][i] - previous[f][i])) * fps < this.maxFootSpeed ? 1 : 0));
    this.previous = g;
    return { x, heading };
  }

  async step(rot, pos, fps) { // -> stylised local rotations, J quaternions
    const first = this.previous === null ? 1 : 0;
    const { x, heading } = this.features(rot, pos, fps);
    const J = this.parents.length, t = (data, dims) => new ort.Tensor("float32", data, dims);
    const poses = {};
    for (const [key, target] of [["target", this.target], ["identity", this.identity]]) {
      const s = this.state[key];
      const out = await this.session.run({
        features: t(x, [1, x.length]), style: t(this.style, [1, this.style.length]), content: t(this.content, [1, this.content.length]),
        target: t(target, [1, target.length]), first_frame: t(new Float32Array([first]), [1, 1]),
        h: t(s.h, [this.S, 1, this.H]), c: t(s.c, [this.S, 1, this.H]),
      });
      this.state[key] = { h: out.h_out.data, c: out.c_out.data };
      const r = out.rotations.data, q = [];
      for (let j = 0; j < J; j++) q.push([r[4 * j], r[4 * j + 1], r[4 * j + 2], r[4 * j + 3]]);
      q[0] = qmul(heading, q[0]);
      poses[key] = q.map(normalize);
    }
    const given = rot.map(normalize);
    const degrees = given.reduce((sum, q, j) => {
      const d = qmul(inverse(poses.identity[j]), q);
      return sum + (360 / Math.PI) * Math.atan2(Math.hypot(d[1], d[2], d[3]), Math.abs(d[0]));
    }, 0) / J;
    const [familiar, unfamiliar] = this.side.familiar_degrees || [FAMILIAR, UNFAMILIAR];
    const now = Math.min(1, Math.max(0, (degrees - familiar) / (unfamiliar - familiar)));
    const [rise, release] = this.side.unfamiliar_rise_release || [RISE, RELEASE];
    const last = this.unfamiliar; // down by at most release and up by at most rise a frame
    this.unfamiliar = first ? now : Math.min(Math.max(now, last - release), last + rise);
    const change = (j) => (this.change ? this.change[j] : qmul(inverse(poses.identity[j]), poses.target[j]));
    let turned = given.map((q, j) => normalize(qmul(q, change(j))));
    if (this.moved) { // then turned so that the joints go where the posture moves the input's
      const g = this.previous, axes = this.side.posture_frame === "body" ? bodyAxes(g, this.roles) : headingAxes(heading);
      const limbEnds = this.side.limb_ends || this.parents.map(() => -1); // an older export: no limbs
      const offsets = this.moved.map((o) => o.slice()), eyes = this.side.eyes_above_head;
      // a limb's end's rise: the smooth minimum of it and the way to the eyes (none above them)
      for (const m of eyes === undefined ? [] : limbEnds.filter((m) => m >= 0 && this.moved[m][1] > 0)) {
        const rise = this.moved[m][1], middle = this.moved[this.parents[m]][1];
        const below = Math.max(0, eyes + [0, 1, 2].reduce((sum, k) => sum + (g[this.roles.head][k] - g[m][k]) * axes[1][k], 0));
        const kept = (rise * below) / Math.cbrt(rise ** 3 + below ** 3);
        offsets[m][1] = kept;
        if (middle > 0) offsets[this.parents[m]][1] = (middle * kept) / rise; // the limb rises as one
      }
      const targets = g.map((x, j) => [0, 1, 2].map((k) => x[k] + offsets[j].reduce((sum, o, i) => sum + o * axes[i][k], 0)));
      turned = reach(turned, pos, g, targets, this.parents, limbEnds, this.side.limb_rounds || 0);
    }
    return given.map((_, j) => slerp(poses.target[j], turned[j], this.unfamiliar));
  }
}

// The page: stylise a clip in the browser, compare with the server's output, draw it.
async function main() {
  const status = document.getElementById("status");
  const params = new URLSearchParams(location.search);
  const style = params.get("style") || "elderly";
  const host = await StyleHost.create();
  const which = params.get("clip") || "walk"; // "guard": the walk with the fists held at the chin
  const clip = await (await fetch(`/onnx/reference.json?style=${encodeURIComponent(style)}&clip=${encodeURIComponent(which)}`)).json();
  host.setLabels(clip.input_style, clip.content, { [style]: 1 });
  const J = host.parents.length, T = clip.frames, times = [], out = [];
  let worst = 0;
  for (let t = 0; t < T; t++) {
    const rot = [], pos = [];
    for (let j = 0; j < J; j++) {
      rot.push(clip.rotations.slice((t * J + j) * 4, (t * J + j) * 4 + 4));
      pos.push(clip.positions.slice((t * J + j) * 3, (t * J + j) * 3 + 3));
    }
    const t0 = performance.now();
    const q = await host.step(rot, pos, clip.fps);
    times.push(performance.now() - t0);
    out.push({ q, pos });
    for (let j = 0; j < J; j++) {
      const s = clip.stylised.slice((t * J + j) * 4, (t * J + j) * 4 + 4);
      const sign = q[j][0] * s[0] + q[j][1] * s[1] + q[j][2] * s[2] + q[j][3] * s[3] < 0 ? -1 : 1;
      for (let k = 0; k < 4; k++) worst = Math.max(worst, Math.abs(sign * q[j][k] - s[k]));
    }
  }
  const sorted = [...times].slice(10).sort((a, b) => a - b);
  window.result = { frames: T, style, clip: which, max_abs_difference: worst, p50_ms: sorted[Math.floor(sorted.length / 2)], p99_ms: sorted[Math.floor(sorted.length * 0.99)] };
  status.textContent = `${T} frames of the ${which} stylised into ${style} in the browser (onnxruntime-web, wasm): ` +
    `per frame p50 ${window.result.p50_ms.toFixed(3)} ms; largest difference from the server's output ${worst.toExponential(2)}`;
  draw(out, host.parents);
}

function draw(frames, parents) { // the stylised clip as side-view stick figures, every 10th frame
  const canvas = document.getElementById("view"), ctx = canvas.getContext("2d");
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, canvas.width, canvas.height);
  const shown = frames.filter((_, t) => t % 10 === 0);
  shown.forEach(({ q, pos }, i) => {
    const gRot = [], g = [];
    parents.forEach((p, j) => {
      if (p < 0) { gRot.push(q[j]); g.push([0, pos[j][1], 0]); } else { gRot.push(qmul(gRot[p], q[j])); g.push(qrot(gRot[p], pos[j]).map((x, k) => x + g[p][k])); }
    });
    const scale = canvas.height / 220, x0 = 40 + i * (canvas.width - 80) / Math.max(1, shown.length - 1);
    ctx.strokeStyle = "#c0392b"; ctx.lineWidth = 2;
    parents.forEach((p, j) => {
      if (p < 0) return;
      ctx.beginPath();
      ctx.moveTo(x0 + g[p][2] * scale, canvas.height - 10 - g[p][1] * scale);
      ctx.lineTo(x0 + g[j][2] * scale, canvas.height - 10 - g[j][1] * scale);
      ctx.stroke();
    });
  });
}

if (document.getElementById("view")) {
  main().catch((e) => { document.getElementById("status").textContent = `error: ${e}`; console.error(e); window.result = { error: String(e) }; });
}
