"""``transfer -o out.glb --mesh``: a skinned body that the Khronos glTF validator passes with
no error and no warning, and that three.js's GLTFLoader loads, skins and plays in Chromium."""

import contextlib
import functools
import http.server
import json
import os
import shutil
import subprocess
import threading
from pathlib import Path

import pytest

from styleerd.model.checkpoint import load_generator
from styleerd.motion import bvh
from styleerd.motion.procedural import rig_variants
from styleerd.runtime.offline import TransferOptions, transfer_file

ROOT = Path(__file__).resolve().parents[1]
VALIDATOR = ROOT / "node_modules" / "gltf-validator"
THREE = ROOT / "node_modules" / "three"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"

needs_node = pytest.mark.skipif(
    not VALIDATOR.exists() or not shutil.which("node"), reason="gltf-validator not installed (make install runs npm ci)"
)

VALIDATE = """
const fs = require('fs');
const validator = require(process.argv[2]);
validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[3])), {maxIssues: 200})
  .then(r => console.log(JSON.stringify(r)), e => { console.error(String(e)); process.exit(1); });
"""


def validate(path: Path) -> dict:
    script = path.with_name("validate.cjs")
    script.write_text(VALIDATE)
    out = subprocess.run(
        ["node", str(script), str(VALIDATOR), str(path)], capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.fixture(scope="module")
def model():
    return load_generator()


@needs_node
@pytest.mark.parametrize(
    "rig",
    ["Mixamo T-pose, centimetres", "joint frames rolled about their bones", "Blender names and proportions, metres"],
)
def test_mesh_glb_passes_the_khronos_validator(model, tmp_path, rig):
    g, meta = model
    bvh.write(tmp_path / "in.bvh", rig_variants()[rig][:90])
    transfer_file(
        tmp_path / "in.bvh",
        tmp_path / "out.glb",
        g,
        meta["data"]["fps"],
        TransferOptions({"elderly": 1.0}, input_style="normal", content="walk", mesh=True),
    )
    report = validate(tmp_path / "out.glb")
    issues = report["issues"]
    assert (issues["numErrors"], issues["numWarnings"]) == (0, 0), issues["messages"][:10]
    assert (
        report["info"]["totalVertexCount"] > 0 and report["info"]["animationCount"] == 1 and report["info"]["hasSkins"]
    )


@needs_node
@pytest.mark.slow
def test_mesh_glb_of_real_clips_passes_the_validator(model, tmp_path, shared_data):
    g, meta = model
    for path in [shared_data / "xia-sample" / "neutral_01_000.bvh"]:
        transfer_file(
            path,
            tmp_path / "out.glb",
            g,
            meta["data"]["fps"],
            TransferOptions({"feminine": 1.0}, input_style="normal", mesh=True),
        )
        issues = validate(tmp_path / "out.glb")["issues"]
        assert (issues["numErrors"], issues["numWarnings"]) == (0, 0), issues["messages"][:10]


PAGE = """<!doctype html><html><head><meta charset="utf-8">
<script type="importmap">
{"imports": {"three": "./three/build/three.module.js", "three/addons/": "./three/examples/jsm/"}}
</script>
</head><body style="margin:0;background:#fff"><canvas id="c" width="640" height="480"></canvas>
<script type="module">
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
const renderer = new THREE.WebGLRenderer({ canvas: document.getElementById("c"), preserveDrawingBuffer: true });
renderer.setClearColor(0xffffff);
const scene = new THREE.Scene();
scene.add(new THREE.HemisphereLight(0xffffff, 0x444444, 2.0));
const camera = new THREE.PerspectiveCamera(40, 640 / 480, 0.01, 100);
new GLTFLoader().load("out.glb", (gltf) => {
  scene.add(gltf.scene);
  let skinned = null;
  gltf.scene.traverse((o) => { if (o.isSkinnedMesh) skinned = o; });
  const mixer = new THREE.AnimationMixer(gltf.scene);
  mixer.clipAction(gltf.animations[0]).play();
  mixer.setTime(0.5);
  gltf.scene.updateMatrixWorld(true);
  const box = new THREE.Box3().setFromObject(skinned, true);
  const centre = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3());
  camera.position.set(centre.x + size.y * 1.2, centre.y + size.y * 0.2, centre.z + size.y * 1.8);
  camera.lookAt(centre);
  renderer.render(scene, camera);
  window.result = { bones: skinned.skeleton.bones.length, height: size.y, duration: gltf.animations[0].duration };
}, undefined, (e) => { window.result = { error: String(e) }; });
</script></body></html>"""


@needs_node
@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="Chromium not installed (.ci/run installs Debian's chromium)")
def test_three_gltf_loader_skins_and_plays_the_body(model, tmp_path):
    g, meta = model
    walk = rig_variants()["Mixamo T-pose, centimetres"][:120]
    bvh.write(tmp_path / "in.bvh", walk)
    transfer_file(
        tmp_path / "in.bvh",
        tmp_path / "out.glb",
        g,
        meta["data"]["fps"],
        TransferOptions({"elderly": 1.0}, input_style="normal", content="walk", mesh=True),
    )
    (tmp_path / "index.html").write_text(PAGE)
    os.symlink(THREE, tmp_path / "three")
    with served_page(tmp_path, 640, 480) as page:
        page.wait_for_function("window.result !== undefined", timeout=30000)
        result = page.evaluate("window.result")
        assert "error" not in result and not page.problems, (result, page.problems)
        assert result["bones"] == walk.skeleton.n_joints
        assert 1.4 < result["height"] < 2.2  # metres: a person's height, skinned and posed
        assert abs(result["duration"] - (walk.n_frames - 1) / walk.fps) < 1e-3
        covered = page.evaluate("""() => {
            const c = document.getElementById('c'), x = document.createElement('canvas');
            x.width = c.width; x.height = c.height; const k = x.getContext('2d'); k.drawImage(c, 0, 0);
            const d = k.getImageData(0, 0, c.width, c.height).data; let n = 0;
            for (let i = 0; i < d.length; i += 4) n += d[i] + d[i + 1] + d[i + 2] < 700;
            return n / (d.length / 4); }""")
        assert covered > 0.02, covered  # the body is drawn
        page.screenshot(path=str(Path(os.environ.get("STYLEERD_GLB_SCREENSHOT") or tmp_path / "glb.png")))


@contextlib.contextmanager
def served_page(folder: Path, width: int, height: int):
    """``folder`` served on loopback and its index.html open in headless Chromium (a software
    WebGL); yields the page, with ``page.problems``: the errors the page raised."""
    from playwright.sync_api import sync_playwright

    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(folder))
    )
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=CHROMIUM,
                args=[
                    "--no-sandbox",
                    "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader",
                    "--no-first-run",
                    "--disable-background-networking",
                ],
            )
            page = browser.new_page(viewport={"width": width, "height": height})
            page.problems = []
            page.on("pageerror", lambda e: page.problems.append(str(e)))
            page.goto(f"http://127.0.0.1:{server.server_address[1]}/index.html")
            yield page
            browser.close()
    finally:
        server.shutdown()
