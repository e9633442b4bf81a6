"""Looked at in the real loaders: three-vrm's VRMLoaderPlugin opens the avatar wearing a
stylised walk (a Character Creator rig's, ``--onto``) and plays it skinned in Chromium;
three-vrm-animation's VRMAnimationLoaderPlugin opens the same walk written as a VRM Animation
(``-o walk.vrma``) and plays it on the plain avatar. Limbs checked on both (hands at their own
sides, feet at the floor, the avatar walking); a screenshot of the two side by side is kept."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_gltf_mesh import CHROMIUM, VALIDATOR, served_page, validate

from styleerd.motion import bvh
from styleerd.motion.procedural import rig_families

ROOT = Path(__file__).resolve().parents[1]
MODULES = ROOT / "node_modules"
needs_vrm = pytest.mark.skipif(
    not (MODULES / "@pixiv" / "three-vrm").exists() or not Path(CHROMIUM).exists() or not VALIDATOR.exists(),
    reason="three-vrm (make install runs npm ci) or Chromium (.ci/run installs it) missing",
)

PAGE = """<!doctype html><html><head><meta charset="utf-8">
<script type="importmap">
{"imports": {"three": "./m/three/build/three.module.js", "three/addons/": "./m/three/examples/jsm/",
 "@pixiv/three-vrm": "./m/@pixiv/three-vrm/lib/three-vrm.module.js",
 "@pixiv/three-vrm-animation": "./m/@pixiv/three-vrm-animation/lib/three-vrm-animation.module.js"}}
</script>
</head><body style="margin:0;background:#fff"><canvas id="c" width="640" height="640"></canvas>
<script type="module">
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { VRMLoaderPlugin, VRMUtils } from "@pixiv/three-vrm";
import { VRMAnimationLoaderPlugin, createVRMAnimationClip } from "@pixiv/three-vrm-animation";
const loader = new GLTFLoader();
loader.register((p) => new VRMLoaderPlugin(p));
loader.register((p) => new VRMAnimationLoaderPlugin(p));
const renderer = new THREE.WebGLRenderer({ canvas: document.getElementById("c"), preserveDrawingBuffer: true });
renderer.setClearColor(0xffffff);
const camera = new THREE.PerspectiveCamera(35, 1, 0.01, 100);

// Plays a clip on an avatar and reads its limbs every 0.1 s; draws the frame at 1 s.
function play(vrm, clip, canvasX) {
  const scene = new THREE.Scene();
  scene.add(new THREE.HemisphereLight(0xffffff, 0x666666, 2.5));
  scene.add(vrm.scene);
  const mixer = new THREE.AnimationMixer(vrm.scene);
  mixer.clipAction(clip).play();
  const bone = (n) => vrm.humanoid.getRawBoneNode(n).getWorldPosition(new THREE.Vector3());
  const pose = (t) => { mixer.setTime(t); vrm.update(0); vrm.scene.updateMatrixWorld(true); };
  const frames = [];
  for (let t = 0; t < clip.duration; t += 0.1) {
    pose(t);
    const across = bone("leftUpperLeg").sub(bone("rightUpperLeg")).setY(0).normalize();
    const middle = bone("leftUpperLeg").add(bone("rightUpperLeg")).multiplyScalar(0.5);
    frames.push({ left: bone("leftHand").sub(middle).dot(across), right: bone("rightHand").sub(middle).dot(across),
                  feet: Math.min(bone("leftFoot").y, bone("rightFoot").y, bone("leftToes").y, bone("rightToes").y),
                  hips: [bone("hips").x, bone("hips").z] });
  }
  pose(1.0);
  const box = new THREE.Box3().setFromObject(vrm.scene, true);
  const centre = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3());
  camera.position.set(centre.x + size.y * 0.9, centre.y + size.y * 0.1, centre.z + size.y * 2.2);
  camera.lookAt(centre);
  renderer.setScissorTest(true);
  renderer.setViewport(canvasX, 0, 320, 640);
  renderer.setScissor(canvasX, 0, 320, 640);
  camera.aspect = 0.5;
  camera.updateProjectionMatrix();
  renderer.render(scene, camera);
  return { frames, duration: clip.duration };
}

try {
  const worn = await loader.loadAsync("worn.vrm");
  worn.userData.vrm.humanoid.autoUpdateHumanBones = false;  // the file's own animation drives the bones
  const own = play(worn.userData.vrm, worn.animations[0], 0);
  const avatar = (await loader.loadAsync("avatar.vrm")).userData.vrm;
  VRMUtils.rotateVRM0(avatar);  // as three-vrm apps do: a VRM 0.x avatar turned to face +Z, as VRMA motion does
  const vrma = (await loader.loadAsync("walk.vrma")).userData.vrmAnimations[0];
  const clip = createVRMAnimationClip(vrma, avatar);
  const fromVrma = play(avatar, clip, 320);
  window.result = { own, fromVrma, vrmaTracks: clip.tracks.length };
} catch (e) { window.result = { error: String(e && e.stack || e) }; }
</script></body></html>"""


def transfer(*args) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "transfer", *map(str, args)],
        capture_output=True,
        text=True,
        check=False,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr


@needs_vrm
def test_three_vrm_plays_the_avatar_wearing_the_walk_and_the_vrma(shared_data, tmp_path):
    walk = rig_families()["Character Creator (CC_Base_, twist and share bones, RL_BoneRoot)"][0][:240]
    bvh.write(tmp_path / "walk.bvh", walk)
    avatar = shared_data / "characters" / "Godette.vrm"
    os.symlink(avatar, tmp_path / "avatar.vrm")
    transfer(tmp_path / "walk.bvh", "--style", "elderly", "--onto", avatar, "-o", tmp_path / "worn.vrm")
    transfer(tmp_path / "walk.bvh", "--style", "elderly", "--onto", avatar, "-o", tmp_path / "walk.vrma")
    issues = validate(tmp_path / "walk.vrma")["issues"]
    assert (issues["numErrors"], issues["numWarnings"]) == (0, 0), issues["messages"][:5]
    (tmp_path / "index.html").write_text(PAGE)
    os.symlink(MODULES, tmp_path / "m")
    with served_page(tmp_path, 640, 640) as page:
        page.wait_for_function("window.result !== undefined", timeout=60000)
        result = page.evaluate("window.result")
        assert "error" not in result and not page.problems, (result, page.problems)
        shot = Path(os.environ.get("STYLEERD_VRM_SCREENSHOT") or tmp_path / "vrm.png")
        page.screenshot(path=str(shot))
    for played in (result["own"], result["fromVrma"]):  # the avatar's file, then the VRMA on the plain avatar
        frames = played["frames"]
        assert abs(played["duration"] - (walk.n_frames - 1) / walk.fps) < 0.05
        left, right = np.array([f["left"] for f in frames]), np.array([f["right"] for f in frames])
        assert (left > 0.05).all() and (right < -0.05).all()  # metres: each hand at its own side, no arm across
        feet = np.array([f["feet"] for f in frames])
        assert -0.03 < feet.min() and np.median(feet) < 0.12  # on the floor (ankles a few cm up), never 3 cm in it
        hips = np.array([f["hips"] for f in frames])
        assert np.linalg.norm(hips[-1] - hips[0]) > 0.5  # it walks
    assert result["vrmaTracks"] > 15
    assert shot.stat().st_size > 10_000
