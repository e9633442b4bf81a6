// styleerd viewer: plays a BVH through the style server frame by frame (the same protocol as
// any mocap client, docs/PROTOCOL.md) and draws input and stylised output side by side; or, in
// live mode, watches a stream that another client sends.
import * as THREE from "three";
import { OrbitControls } from "/static/vendor/OrbitControls.js";
import { GLTFLoader } from "/static/vendor/loaders/GLTFLoader.js";
import { VRMHumanoid, VRMLoaderPlugin } from "@pixiv/three-vrm";

const $ = (id) => document.getElementById(id);
const ui = {
  clip: $("clip"), upload: $("upload"), avatar: $("avatar"), live: $("live"), styleA: $("styleA"), styleB: $("styleB"),
  mix: $("mix"), intensity: $("intensity"), play: $("play"), scrub: $("scrub"),
  frame: $("frame"), status: $("status"), error: $("error"),
};
// What tests and curious users can read: the last drawn frames, the server's replies.
const viewer = (window.viewer = { ready: false, framesDrawn: 0, drawn: new Map(), target: null, mode: "clip", avatarFrames: 0 });

// ---- scene: two characters of solid bones on a floor ----
const stage = $("stage");
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
stage.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xeef1f5);
const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 1e5);
const controls = new OrbitControls(camera, renderer.domElement);
scene.add(new THREE.HemisphereLight(0xffffff, 0x8090a0, 2.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(1, 2, 1.5);
scene.add(sun);
let grid = null;

function resize() {
  const { clientWidth: w, clientHeight: h } = stage;
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(1, h);
  camera.updateProjectionMatrix();
}
window.addEventListener("resize", resize);

class Figure {
  // One skeleton drawn as oriented bones (boxes with a fin on their front, so a bone rolled
  // about itself shows) and joint spheres.
  constructor(parents, radius, color) {
    this.parents = parents;
    const material = new THREE.MeshStandardMaterial({ color, roughness: 0.55, metalness: 0.05 });
    const finMaterial = new THREE.MeshStandardMaterial({ color: 0x222222, roughness: 0.6 });
    const jointMaterial = new THREE.MeshStandardMaterial({ color: new THREE.Color(color).multiplyScalar(0.8), roughness: 0.5 });
    this.group = new THREE.Group();
    const box = new THREE.BoxGeometry(radius * 1.9, 1, radius * 1.3);
    const fin = new THREE.BoxGeometry(radius * 0.35, 0.8, radius * 0.9).translate(0, 0, radius * 0.95);
    this.bones = parents.map((p) => {
      if (p < 0) return null;
      const bone = new THREE.Group();
      bone.add(new THREE.Mesh(box, material));
      bone.add(new THREE.Mesh(fin, finMaterial));
      this.group.add(bone);
      return bone;
    });
    this.joints = parents.map(() => {
      const mesh = new THREE.Mesh(new THREE.SphereGeometry(radius * 1.15, 14, 10), jointMaterial);
      this.group.add(mesh);
      return mesh;
    });
    scene.add(this.group);
  }
  pose(positions, fronts, shift) {
    const p = (j) => new THREE.Vector3(positions[3 * j] + shift, positions[3 * j + 1], positions[3 * j + 2]);
    const basis = new THREE.Matrix4();
    this.parents.forEach((parent, j) => {
      const at = p(j);
      this.joints[j].position.copy(at);
      const bone = this.bones[j];
      if (!bone) return;
      const from = p(parent);
      const d = at.clone().sub(from);
      const length = d.length();
      bone.visible = length > 1e-6;
      if (!bone.visible) return;
      d.divideScalar(length);
      // the bone's frame: y along the bone, z its front (fronts from the server), x across
      let front = new THREE.Vector3(fronts[3 * j], fronts[3 * j + 1], fronts[3 * j + 2]);
      front.addScaledVector(d, -front.dot(d));
      if (front.lengthSq() < 1e-8) front = new THREE.Vector3(0, 0, 1).addScaledVector(d, -d.z);
      front.normalize();
      const across = new THREE.Vector3().crossVectors(d, front);
      basis.makeBasis(across, d, front);
      bone.position.copy(from).addScaledVector(d, 0.5 * length);
      bone.quaternion.setFromRotationMatrix(basis);
      bone.scale.set(1, length, 1);
    });
  }
  dispose() {
    scene.remove(this.group);
    this.group.traverse((o) => o.geometry && o.geometry.dispose());
  }
}

let figures = null; // [input, output]
let spacing = 100;

function buildFigures(parents, firstPositions) {
  figures?.forEach((f) => f.dispose());
  let lo = Infinity, hi = -Infinity;
  for (let j = 0; j < parents.length; j++) { lo = Math.min(lo, firstPositions[3 * j + 1]); hi = Math.max(hi, firstPositions[3 * j + 1]); }
  const height = Math.max(1e-3, hi - lo);
  spacing = height * 0.9;
  const radius = height * 0.028;
  figures = [new Figure(parents, radius, 0x6f8fbf), new Figure(parents, radius, 0xe0703c)];
  if (grid) scene.remove(grid);
  grid = new THREE.GridHelper(height * 40, 80, 0xaab4c4, 0xd0d6df);
  grid.position.y = lo - radius;
  scene.add(grid);
  camera.near = height / 100; camera.far = height * 200; camera.updateProjectionMatrix();
  camera.position.set(height * 1.2, height * 0.9, height * 2.8);
  controls.target.set(0, lo + height * 0.5, 0);
}

// ---- files the server reads for the page: a glTF motion into BVH text, a GLB avatar into its humanoid ----
const PIECE = 1 << 19; // bytes a message: under the server's message limit (1 MiB)
// the page's own query goes with every socket: a load balancer routes a watcher by its token or server
// (deploy/haproxy.cfg); wss behind a TLS proxy
const socketUrl = () => `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/${location.search}`;
const pageQuery = new URLSearchParams(location.search);

/** What the page's address asks to watch: ?stream=NAME&token=TOKEN&index=K (each optional). */
function watchTarget() {
  const target = {};
  if (pageQuery.get("stream")) target.stream = pageQuery.get("stream");
  if (pageQuery.get("token")) target.token = pageQuery.get("token");
  if (pageQuery.get("index")) target.index = Number(pageQuery.get("index"));
  return target;
}

function upload(file, purpose) {
  return new Promise((resolve, reject) => {
    const sock = new WebSocket(socketUrl());
    sock.binaryType = "arraybuffer";
    sock.onopen = async () => {
      const bytes = new Uint8Array(await file.arrayBuffer());
      sock.send(JSON.stringify({ type: "upload", purpose, name: file.name, bytes: bytes.length }));
      for (let at = 0; at < bytes.length; at += PIECE) sock.send(bytes.subarray(at, at + PIECE));
    };
    let answer = null; // an FBX avatar's answer is followed by the GLB the server made of it
    sock.onmessage = (event) => {
      if (answer) { answer.glbBytes = event.data; sock.close(); resolve(answer); return; }
      const msg = JSON.parse(event.data);
      if (msg.type === "error") { sock.close(); reject(new Error(msg.message)); return; }
      if (msg.glb) { answer = msg; return; }
      sock.close();
      resolve(msg);
    };
    sock.onclose = (event) => reject(new Error(event.reason || `the server closed the upload (${event.code})`));
  });
}

// ---- the user's avatar (VRM, or a GLB character), twice (input and output), driven by the frames' humanoid pose ----
let avatars = null; // [input, output]: VRMs, or a GLB's scene with a three-vrm humanoid on its bones
let humanoidLayout = null; // the server's: bones of the model's joints, their parents, the hips' T-pose height

async function glbAvatar(gltf, rig) {
  // the server's T-pose first (VRM's rest: three-vrm's humanoid takes the pose it is built in as its rest)
  const node = (index) => gltf.parser.getDependency("node", index);
  for (const [index, q] of Object.entries(rig.tpose)) (await node(Number(index))).quaternion.fromArray(q);
  gltf.scene.updateMatrixWorld(true);
  const bones = {};
  for (const [name, index] of Object.entries(rig.bones)) bones[name] = { node: await node(index) };
  const humanoid = new VRMHumanoid(bones);
  gltf.scene.add(humanoid.normalizedHumanBonesRoot);
  // a GLB's units are its own (RobotExpressive stands 3 units tall): it is shown as tall as the model's person
  return { scene: gltf.scene, humanoid, meta: null, update: () => humanoid.update(), fitToPerson: true };
}

async function loadAvatar(file) {
  const glb = /\.(glb|fbx)$/i.test(file.name); // an FBX is made a GLB by the server (with Blender's bpy)
  const rig = glb ? await upload(file, "avatar") : null; // the server maps its joints, as `transfer --onto` does
  const loader = new GLTFLoader();
  if (!glb) loader.register((parser) => new VRMLoaderPlugin(parser));
  const url = URL.createObjectURL(rig?.glbBytes ? new Blob([rig.glbBytes]) : file);
  try {
    const loaded = await Promise.all([loader.loadAsync(url), loader.loadAsync(url)]);
    const vrms = glb ? await Promise.all(loaded.map((g) => glbAvatar(g, rig))) : loaded.map((g) => g.userData.vrm);
    if (vrms.some((v) => !v)) throw new Error("not a VRM avatar (no VRM humanoid in the file)");
    avatars?.forEach((v) => scene.remove(v.scene));
    avatars = vrms;
    avatars.forEach((v) => scene.add(v.scene));
    viewer.avatar = file.name;
    viewer.avatarFrames = 0;
    avatarGap = null;
  } finally { URL.revokeObjectURL(url); }
}

function poseAvatar(vrm, data, shift, unitsPerMetre) {
  // the server's pose is VRM 1.0's (facing +Z); a VRM 0.x avatar faces -Z: turned as three-vrm's VRMA player does
  const flip = vrm.meta?.metaVersion === "0" ? -1 : 1;
  const bones = humanoidLayout.bones;
  bones.forEach((name, k) => {
    const node = name && vrm.humanoid.getNormalizedBoneNode(name);
    if (node) node.quaternion.set(flip * data[4 * k], data[4 * k + 1], flip * data[4 * k + 2], data[4 * k + 3]);
  });
  const at = 4 * bones.length, hips = vrm.humanoid.getNormalizedBoneNode("hips");
  const scale = vrm.humanoid.normalizedRestPose.hips.position[1] / humanoidLayout.hips_height;
  hips.position.set(flip * data[at] * scale, data[at + 1] * scale, flip * data[at + 2] * scale);
  vrm.scene.scale.setScalar(unitsPerMetre * (vrm.fitToPerson ? 1 / scale : 1));
  vrm.scene.position.set(shift, 0, 0);
  vrm.update(1 / 30);
}

function drawAvatars(floats, from) {
  if (!avatars || !humanoidLayout || !figures) return;
  const n = humanoidLayout.bones.length * 4 + 3;
  if (floats.length < from + 2 * n) return;
  const unitsPerMetre = spacing / 0.9 / 1.7; // the figures' height (spacing is 0.9 of it) as a 1.7 m person
  const gap = avatarGap ?? spacing;
  poseAvatar(avatars[0], floats.subarray(from, from + n), -gap / 2, unitsPerMetre);
  poseAvatar(avatars[1], floats.subarray(from + n, from + 2 * n), gap / 2, unitsPerMetre);
  figures.forEach((f) => (f.group.visible = false));
  if (avatarGap === null) frameAvatars();
  viewer.avatarFrames += 1;
}

let avatarGap = null; // how far apart the two avatars stand: wide characters further than the figures
function frameAvatars() {
  // once an avatar is posed: side by side without touching, the camera on the pair, heads included (measured on
  // the humanoid's bones: a mesh's bounds can be far from what it shows)
  const box = new THREE.Box3();
  for (const name of ["head", "leftHand", "rightHand", "leftFoot", "rightFoot", "leftUpperArm", "rightUpperArm"]) {
    const node = avatars[1].humanoid.getRawBoneNode(name);
    if (node) box.expandByPoint(node.getWorldPosition(new THREE.Vector3()));
  }
  const floor = grid ? grid.position.y : 0, height = 1.2 * (box.max.y - floor), width = 1.3 * (box.max.x - box.min.x);
  avatarGap = Math.max(spacing, width);
  controls.target.set(0, floor + height / 2, 0);
  camera.position.set(height * 0.8, floor + height * 0.8, (height + avatarGap) * 1.6);
  follow = null;
}

// What a test reads: each avatar's hands across the body (+ left) and feet height, in metres as shown
viewer.avatarLimbs = () => avatars?.map((vrm) => {
  const metres = spacing / 0.9 / 1.7; // units a metre, as drawAvatars shows them
  const p = (n) => vrm.humanoid.getRawBoneNode(n).getWorldPosition(new THREE.Vector3()).divideScalar(metres);
  const across = p("leftUpperLeg").sub(p("rightUpperLeg")).setY(0).normalize();
  const middle = p("leftUpperLeg").add(p("rightUpperLeg")).multiplyScalar(0.5);
  return { left: p("leftHand").sub(middle).dot(across), right: p("rightHand").sub(middle).dot(across),
           feet: Math.min(p("leftFoot").y, p("rightFoot").y) };
});

let follow = null; // the camera follows the characters' root
function draw(seq, input, output, inputFronts, outputFronts) {
  if (!figures) return;
  figures[0].pose(input, inputFronts, -spacing / 2);
  figures[1].pose(output, outputFronts, spacing / 2);
  const root = new THREE.Vector3(input[0], input[1], input[2]);
  if (follow) {
    const delta = root.clone().sub(follow);
    delta.y = 0;
    camera.position.add(delta);
    controls.target.add(delta);
  }
  follow = root;
  viewer.framesDrawn += 1;
  viewer.lastSeq = seq;
  viewer.drawn.set(seq, Array.from(output));
  if (viewer.drawn.size > 2000) viewer.drawn.delete(viewer.drawn.keys().next().value);
}

function animate() {
  controls.update();
  renderer.render(scene, camera);
  requestAnimationFrame(animate);
}

// ---- BVH text -> header (sent to the server) and frames (channel values) ----
function parseBVH(text) {
  const at = text.search(/^\s*MOTION\s*$/m);
  if (at < 0) throw new Error("not a BVH file: no MOTION section");
  const header = text.slice(0, at);
  const lines = text.slice(at).split(/\r?\n/).map((l) => l.trim()).filter((l) => l.length);
  const count = parseInt((lines[1] || "").split(":")[1], 10);
  const frameTime = parseFloat((lines[2] || "").split(":")[1]);
  if (!(count >= 0) || !(frameTime > 0)) throw new Error("BVH: bad 'Frames:' or 'Frame Time:' line");
  const frames = lines.slice(3, 3 + count).map((l) => Float32Array.from(l.split(/\s+/), Number));
  if (frames.length === 0) throw new Error("BVH: the motion has no frames");
  return { header, fps: 1 / frameTime, frames };
}

// ---- the connection ----
let ws = null;
let clip = null; // {header, fps, frames}
let joints = 0, channels = 0;
let frameIndex = 0;
let playing = true;
let timer = null;
let sentAt = new Map();
let latency = 0;

function targetMessage() {
  const a = ui.styleA.value, b = ui.styleB.value, m = parseFloat(ui.mix.value), intensity = parseFloat(ui.intensity.value);
  if (b && m > 0 && b !== a) return { mix: { [a]: 1 - m, [b]: m }, intensity };
  return { style: a, intensity };
}

const partSelects = () => Array.from(document.querySelectorAll("#parts select"));

function partsMessage() {
  // body parts with their own target: fixed for a stream, so a change restarts the clip's stream
  const parts = {};
  for (const el of partSelects()) if (el.value) parts[el.dataset.part] = el.value;
  return Object.keys(parts).length ? { parts } : {};
}

function setStatus(text) { ui.status.textContent = text; }
function fail(text) { ui.error.textContent = text; }

function connect(hello, onReady) {
  if (ws) { ws.onclose = null; ws.close(); }
  clearInterval(timer);
  viewer.ready = false;
  fail("");
  ws = new WebSocket(socketUrl());
  ws.binaryType = "arraybuffer";
  ws.onopen = () => ws.send(JSON.stringify(hello));
  ws.onclose = (e) => { viewer.ready = false; setStatus(`closed (${e.code}${e.reason ? ": " + e.reason : ""})`); };
  ws.onmessage = (event) => {
    if (typeof event.data === "string") {
      const msg = JSON.parse(event.data);
      if (msg.type === "error") fail(msg.message);
      else if (msg.type === "target") { viewer.target = msg.weights; showTarget(); }
      else onReady(msg);
      return;
    }
    const view = new DataView(event.data);
    const seq = view.getUint32(0, true);
    const floats = new Float32Array(event.data, 4);
    const skip = viewer.mode === "clip" ? channels : 0;
    const input = floats.subarray(skip, skip + 3 * joints), output = floats.subarray(skip + 3 * joints, skip + 6 * joints);
    const inputFronts = floats.subarray(skip + 6 * joints, skip + 9 * joints), outputFronts = floats.subarray(skip + 9 * joints, skip + 12 * joints);
    if (sentAt.has(seq)) { latency = 0.9 * latency + 0.1 * (performance.now() - sentAt.get(seq)); sentAt.delete(seq); }
    if (!figures) buildFigures(viewer.parents, input);
    draw(seq, input, output, inputFronts, outputFronts);
    drawAvatars(floats, skip + 12 * joints);
    if (viewer.mode === "clip") { ui.frame.textContent = `${seq + 1} / ${clip.frames.length}`; ui.scrub.value = seq; }
  };
}

function showTarget() {
  const w = Object.entries(viewer.target || {}).map(([k, v]) => `${k} ${v.toFixed(2)}`).join(", ");
  setStatus(`${viewer.mode === "live" ? "live: " + (viewer.stream || "waiting") : "stream ready"} · target ${w} · latency ${latency.toFixed(1)} ms`);
}

function playClip(c) {
  clip = c;
  viewer.mode = "clip";
  ui.live.classList.remove("on");
  figures?.forEach((f) => f.dispose());
  figures = null; follow = null; avatarGap = null;
  frameIndex = 0;
  ui.scrub.max = clip.frames.length - 1;
  const hello = { type: "hello", skeleton: clip.header, fps: clip.fps, format: "binary", positions: true, fronts: true, name: "viewer", private: true, humanoid: !!avatars, ...targetMessage(), ...partsMessage() };
  viewer.drawn.clear();
  connect(hello, (msg) => {
    if (msg.type !== "ready") return;
    joints = msg.joints.length; channels = msg.channels; humanoidLayout = msg.humanoid || null;
    viewer.parents = msg.parents; viewer.ready = true; viewer.target = msg.target; viewer.parts = msg.parts;
    showTarget();
    timer = setInterval(tick, 1000 / clip.fps);
  });
}

function sendFrame(i) {
  const values = clip.frames[i];
  if (values.length !== channels) { fail(`frame ${i + 1} has ${values.length} values, the skeleton ${channels} channels`); playing = false; return; }
  const buffer = new ArrayBuffer(4 + 4 * channels);
  new DataView(buffer).setUint32(0, i, true);
  new Float32Array(buffer, 4).set(values);
  sentAt.set(i, performance.now());
  ws.send(buffer);
}

function tick() {
  if (!playing || !viewer.ready || ws.bufferedAmount > 1 << 16) return;
  if (frameIndex >= clip.frames.length) seek(0); // loop: an online model starts over
  sendFrame(frameIndex++);
  if (frameIndex % 15 === 0) showTarget();
}

function seek(i) {
  // The model is online: after a jump it starts afresh from that frame, as a live stream would.
  ws.send(JSON.stringify({ type: "reset" }));
  sentAt.clear();
  viewer.drawn.clear();
  frameIndex = i;
  if (!playing) sendFrame(frameIndex++);
}

function watchLive() {
  viewer.mode = "live";
  ui.live.classList.add("on");
  figures?.forEach((f) => f.dispose());
  figures = null; follow = null;
  connect({ type: "watch", fronts: true, humanoid: !!avatars, ...watchTarget() }, (msg) => {
    if (msg.type === "waiting") { viewer.ready = true; viewer.stream = null; setStatus(msg.streams.length ? "live: attaching…" : "live: waiting for a stream (styleerd stream-bvh FILE)"); }
    if (msg.type === "watching") {
      joints = msg.joints.length; viewer.parents = msg.parents; viewer.stream = msg.stream; viewer.target = msg.target;
      humanoidLayout = msg.humanoid || null;
      figures?.forEach((f) => f.dispose()); figures = null; follow = null;
      showTarget();
    }
    if (msg.type === "ended") { viewer.stream = null; setStatus(`live: ${msg.stream} ended; waiting for the next stream`); }
  });
}

function sendTarget() {
  ui.mixValue.textContent = parseFloat(ui.mix.value).toFixed(2);
  ui.intensityValue.textContent = parseFloat(ui.intensity.value).toFixed(2);
  if (ws && ws.readyState === WebSocket.OPEN && viewer.ready) ws.send(JSON.stringify({ type: "set", ...targetMessage() }));
}
ui.mixValue = $("mixValue");
ui.intensityValue = $("intensityValue");

async function loadClip(name) {
  try {
    const r = await fetch(`/clips/${encodeURIComponent(name)}`);
    if (!r.ok) throw new Error(`${name}: ${r.status}`);
    playClip(parseBVH(await r.text()));
  } catch (e) { fail(String(e.message || e)); }
}

async function main() {
  resize();
  animate();
  const styles = await (await fetch("/styles")).json();
  for (const s of styles.styles) {
    ui.styleA.add(new Option(s, s, false, s === "elderly"));
    ui.styleB.add(new Option(s, s));
  }
  for (const el of partSelects()) {
    el.add(new Option(`${el.dataset.part}: input`, "input"));
    for (const s of styles.styles) el.add(new Option(`${el.dataset.part}: ${s}`, s));
    el.onchange = () => { if (viewer.mode === "clip" && clip) playClip(clip); };
  }
  const names = await (await fetch("/clips")).json();
  for (const n of names) ui.clip.add(new Option(n, n));
  ui.clip.onchange = () => loadClip(ui.clip.value);
  ui.upload.onchange = async () => {
    const file = ui.upload.files[0];
    if (!file) return;
    try {
      if (file.name.toLowerCase().endsWith(".bvh")) { playClip(parseBVH(await file.text())); return; }
      setStatus(`reading ${file.name}…`); // a VRM Animation or a GLB's first animation, read by the server
      const motion = await upload(file, "motion");
      viewer.uploaded = motion.animation;
      playClip(parseBVH(motion.bvh));
    } catch (e) { fail(`${file.name}: ${e.message}`); }
  };
  ui.avatar.onchange = async () => {
    const file = ui.avatar.files[0];
    if (!file) return;
    try {
      await loadAvatar(file);
      if (viewer.mode === "live") watchLive(); else if (clip) playClip(clip); // the stream again, with the humanoid pose
    } catch (e) { fail(`${file.name}: ${e.message || e}`); }
  };
  ui.live.onclick = () => (viewer.mode === "live" ? loadClip(ui.clip.value) : watchLive());
  for (const el of [ui.styleA, ui.styleB]) el.onchange = sendTarget;
  for (const el of [ui.mix, ui.intensity]) el.oninput = sendTarget;
  ui.play.onclick = () => { playing = !playing; ui.play.textContent = playing ? "pause" : "play"; };
  ui.scrub.oninput = () => { if (viewer.mode === "clip" && viewer.ready) seek(parseInt(ui.scrub.value, 10)); };
  if (pageQuery.get("stream") || pageQuery.get("token")) watchLive(); // a link to a live stream
  else if (names.length) loadClip(names[0]);
}
main().catch((e) => fail(String(e.message || e)));
