"""The browser viewer in headless Chromium (Debian's, driven by Playwright): the page loads and
draws both characters, a style change reaches the server and changes the drawn output, live
mode shows a stream another client sends; a screenshot is saved."""

import os
import shutil
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from styleerd.serve.loadtest import free_port, start_server, stop_server

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]

pytestmark = pytest.mark.skipif(
    not Path(CHROMIUM).exists(), reason="Chromium not installed (.ci/run installs Debian's chromium)"
)


@contextmanager
def chromium_page(url: str, width: int = 1280, height: int = 720, console: bool = False):
    """Debian's Chromium on ``url`` -> (the page, the errors it raises; with ``console``, the
    errors it logs too)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": width, "height": height})
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            if console:
                page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.goto(url)
            yield page, errors
        finally:
            browser.close()


@pytest.fixture(scope="module")
def page():
    port = free_port()
    server = start_server(port)
    with chromium_page(f"http://127.0.0.1:{port}/") as (page, errors):
        page.port, page.errors = port, errors
        yield page
    assert stop_server(server) == 0


def stream_from_another_client(path: Path, port: int, style: str) -> subprocess.Popen:
    """``styleerd stream-bvh`` of ``path`` to the page's server in real time, as a mocap client."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "stream-bvh",
            str(path),
            "--to",
            f"ws://127.0.0.1:{port}/",
            "--style",
            style,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def drawn_after_restart(page, style: str, frame: int = 40) -> np.ndarray:
    """Choose a style, wait for the server's confirmation, restart the clip (the stream
    starts afresh) and return the stylised joint positions drawn at ``frame``."""
    page.select_option("#styleA", style)
    page.wait_for_function(f"window.viewer.target && window.viewer.target['{style}'] === 1", timeout=20000)
    page.eval_on_selector("#scrub", "el => { el.value = 0; el.dispatchEvent(new Event('input')); }")
    page.wait_for_function(f"window.viewer.drawn.has({frame})", timeout=30000)
    return np.array(page.evaluate(f"window.viewer.drawn.get({frame})"))


def test_page_draws_and_a_style_change_changes_the_output(page, tmp_path):
    page.wait_for_function("window.viewer && window.viewer.ready && window.viewer.framesDrawn > 20", timeout=60000)
    assert page.locator("#error").inner_text() == "" and not page.errors
    assert page.locator("#styleA option").count() == 7 and page.locator("#clip option").count() >= 1
    neutral = drawn_after_restart(page, "normal")
    styled = drawn_after_restart(page, "elderly")
    change = np.linalg.norm((styled - neutral).reshape(-1, 3), axis=-1).mean()
    height = np.ptp(neutral.reshape(-1, 3)[:, 1])
    assert change > 0.02 * height, (change, height)  # the output the page drew is a different motion
    assert "target elderly 1.00" in page.locator("#status").inner_text()
    page.wait_for_timeout(500)
    shot = Path(os.environ.get("STYLEERD_SCREENSHOT") or tmp_path / "viewer.png")
    page.screenshot(path=str(shot))
    assert shot.stat().st_size > 10000


def test_body_parts_restart_the_stream_with_targets_of_their_own(page):
    """Choosing a target for a body part restarts the clip's stream with that part (the server
    says which parts it took) and the drawn output changes; back to none, the stream is plain."""
    base = drawn_after_restart(page, "exhausted")
    page.select_option("#part-legs", "elderly")
    page.wait_for_function(
        "window.viewer.ready && window.viewer.parts && window.viewer.parts.legs && window.viewer.parts.legs.elderly "
        "=== 1",
        timeout=30000,
    )
    page.wait_for_function("window.viewer.drawn.has(40)", timeout=30000)
    parts = np.array(page.evaluate("window.viewer.drawn.get(40)"))
    height = np.ptp(base.reshape(-1, 3)[:, 1])
    assert np.linalg.norm((parts - base).reshape(-1, 3), axis=-1).max() > 0.02 * height
    page.select_option("#part-legs", "")
    page.wait_for_function(
        "window.viewer.ready && window.viewer.parts && Object.keys(window.viewer.parts).length === 0", timeout=30000
    )
    assert page.locator("#error").inner_text() == "" and not page.errors


def test_an_uploaded_bvh_plays(page, tmp_path):
    from styleerd.motion import bvh
    from styleerd.motion.procedural import walk

    bvh.write(tmp_path / "mine.bvh", walk(3.0, fps=30.0))  # 90 frames: the demo clip has 360
    page.set_input_files("#upload", str(tmp_path / "mine.bvh"))
    page.wait_for_function("document.getElementById('frame').textContent.endsWith('/ 90')", timeout=30000)
    before = page.evaluate("window.viewer.framesDrawn")
    page.wait_for_function(f"window.viewer.framesDrawn > {before + 10}", timeout=30000)
    assert page.locator("#error").inner_text() == ""
    (tmp_path / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n")
    page.set_input_files("#upload", str(tmp_path / "broken.bvh"))
    page.wait_for_function("document.getElementById('error').textContent.includes('broken.bvh')", timeout=10000)


def test_live_mode_shows_a_stream_from_another_client(page, tmp_path):
    from styleerd.motion import bvh
    from styleerd.motion.procedural import walk

    bvh.write(tmp_path / "walk.bvh", walk(8.0, fps=30.0))
    page.click("#live")
    page.wait_for_function("window.viewer.mode === 'live' && window.viewer.ready", timeout=20000)
    source = stream_from_another_client(tmp_path / "walk.bvh", page.port, "feminine")
    try:
        page.wait_for_function("window.viewer.stream === 'walk'", timeout=30000)
        before = page.evaluate("window.viewer.framesDrawn")
        page.wait_for_function(f"window.viewer.framesDrawn > {before + 30}", timeout=30000)
        assert "live: walk" in page.locator("#status").inner_text()
    finally:
        out, _ = source.communicate(timeout=60)
    assert source.returncode == 0 and "reordered 0" in out, out


def test_a_vrm_avatar_plays_the_input_and_the_stylised_motion_live_too(page, shared_data, tmp_path):
    """The user's VRM avatar (Godette, VRM 0.x), dropped on the page, plays the clip's input and
    its stylised output side by side, driven by the server's humanoid pose; each hand stays on
    its own side of the body and the feet at the floor; in live mode too. Screenshot kept."""
    from styleerd.motion import bvh
    from styleerd.motion.procedural import walk

    if page.evaluate("window.viewer.mode") == "live":
        page.click("#live")  # back to a clip
    page.wait_for_function("window.viewer.mode === 'clip' && window.viewer.ready", timeout=30000)
    page.set_input_files("#avatar", str(shared_data / "characters" / "Godette.vrm"))
    page.wait_for_function("window.viewer.avatar === 'Godette.vrm' && window.viewer.avatarFrames > 40", timeout=60000)
    samples = []
    for _ in range(12):
        page.wait_for_timeout(150)
        samples += page.evaluate("window.viewer.avatarLimbs()")
    left = np.array([s["left"] for s in samples])
    right = np.array([s["right"] for s in samples])
    feet = np.array([s["feet"] for s in samples])
    assert (left > 0.05).all() and (right < -0.05).all(), (left, right)  # metres: no arm across the body
    assert feet.min() > -0.03 and feet.max() < 0.3, feet  # ankles over the floor, a step's lift at most
    assert page.locator("#error").inner_text() == "" and not page.errors
    shot = Path(os.environ.get("STYLEERD_AVATAR_SCREENSHOT") or tmp_path / "avatar.png")
    page.screenshot(path=str(shot))
    assert shot.stat().st_size > 10000
    bvh.write(tmp_path / "walk.bvh", walk(6.0, fps=30.0))
    page.click("#live")
    page.wait_for_function("window.viewer.mode === 'live' && window.viewer.ready", timeout=20000)
    source = stream_from_another_client(tmp_path / "walk.bvh", page.port, "exhausted")
    try:
        page.wait_for_function("window.viewer.stream === 'walk'", timeout=30000)
        before = page.evaluate("window.viewer.avatarFrames")
        page.wait_for_function(f"window.viewer.avatarFrames > {before + 30}", timeout=30000)
    finally:
        out, _ = source.communicate(timeout=60)
    assert source.returncode == 0, out


def test_a_glb_character_plays_an_uploaded_vrm_animation(page, shared_data, tmp_path):
    """A GLB character that is no VRM (RobotExpressive: an A-pose rig named UpperArm.L, Foot.L, with IK
    feet outside its legs) dropped as the avatar, mapped by the server and set in the T-pose there, and a
    VRM Animation dropped as the motion (read into BVH by the server): the character plays its input and
    its stylised output, each hand on its own side of the body, the feet near the floor. A file that is
    not one is refused with its name. Screenshot kept."""
    if page.evaluate("window.viewer.mode") == "live":
        page.click("#live")
    page.wait_for_function("window.viewer.mode === 'clip' && window.viewer.ready", timeout=30000)
    page.set_input_files("#upload", str(shared_data / "characters" / "test.vrma"))
    page.wait_for_function("window.viewer.uploaded !== undefined && window.viewer.ready", timeout=60000)
    page.set_input_files("#avatar", str(shared_data / "characters" / "RobotExpressive.glb"))
    page.wait_for_function(
        "window.viewer.avatar === 'RobotExpressive.glb' && window.viewer.avatarFrames > 20", timeout=60000
    )
    samples = []
    for _ in range(10):
        page.wait_for_timeout(150)
        samples += page.evaluate("window.viewer.avatarLimbs()")
    left, right = np.array([s["left"] for s in samples]), np.array([s["right"] for s in samples])
    feet = np.array([s["feet"] for s in samples])
    assert (left > 0.05).all() and (right < -0.05).all(), (left, right)  # metres as shown: as tall as a person
    assert feet.min() > -0.05 and feet.max() < 0.3, feet
    assert page.locator("#error").inner_text() == "" and not page.errors
    shot = Path(os.environ.get("STYLEERD_GLB_AVATAR_SCREENSHOT") or tmp_path / "glb-avatar.png")
    page.screenshot(path=str(shot))
    assert shot.stat().st_size > 10000
    (tmp_path / "broken.glb").write_bytes(b"glTF" + bytes(60))
    page.set_input_files("#avatar", str(tmp_path / "broken.glb"))
    page.wait_for_function("document.getElementById('error').textContent.includes('broken.glb')", timeout=30000)
