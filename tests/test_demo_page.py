"""The demo page (``styleerd demo``'s index.html, written by ``eval.viewer.write_html``) in
real Chromium: it loads with no console error, its canvases draw the figures, and a bone
rolled about itself looks different (bones are oriented plates, not lines)."""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from styleerd.eval.viewer import write_html
from styleerd.motion import quat
from styleerd.motion.motion import Motion
from styleerd.motion.procedural import walk

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]

pytestmark = pytest.mark.skipif(
    not Path(CHROMIUM).exists(), reason="Chromium not installed (.ci/run installs Debian's chromium)"
)


def open_page(path: Path):
    from playwright.sync_api import sync_playwright

    p = sync_playwright().start()
    browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
    page = browser.new_page(viewport={"width": 1100, "height": 800})
    problems = []
    page.on("pageerror", lambda e: problems.append(str(e)))
    page.on("console", lambda m: problems.append(m.text) if m.type == "error" else None)
    page.goto(path.as_uri())
    return p, browser, page, problems


def drawn_fraction(page, index: int) -> float:
    """The share of canvas ``index``'s pixels that are drawn (its background is transparent)."""
    return page.evaluate(f"""() => {{ const c = document.querySelectorAll('canvas')[{index}];
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let n = 0; for (let i = 3; i < d.length; i += 4) n += d[i] > 0; return n / (d.length / 4); }}""")


def canvas_difference(page, a: int, b: int) -> float:
    """The share of pixels that differ clearly between two canvases."""
    return page.evaluate(f"""() => {{ const c = document.querySelectorAll('canvas');
        const x = c[{a}].getContext('2d').getImageData(0, 0, c[{a}].width, c[{a}].height).data;
        const y = c[{b}].getContext('2d').getImageData(0, 0, c[{b}].width, c[{b}].height).data;
        let n = 0; for (let i = 0; i < x.length; i += 4)
          n += Math.abs(x[i] - y[i]) + Math.abs(x[i + 1] - y[i + 1])
             + Math.abs(x[i + 2] - y[i + 2]) + Math.abs(x[i + 3] - y[i + 3]) > 60;
        return n / (x.length / 4); }}""")


def test_demo_page_draws_in_chromium_and_shows_a_bone_roll(tmp_path):
    plain = walk(2.0, fps=30.0)
    rolled = Motion(plain.skeleton, plain.rotations.copy(), plain.positions, plain.fps)
    arm = plain.skeleton.index("LeftArm")
    twist = quat.from_angle_axis(np.pi / 2, plain.skeleton.offsets[plain.skeleton.index("LeftForeArm")] / 27.0)
    rolled.rotations[:, arm] = quat.mul(rolled.rotations[:, arm], twist)  # the upper arm rolled 90 degrees about itself
    path = tmp_path / "index.html"
    write_html(path, [("walk", plain), ("upper arm rolled", rolled)], "test page")
    p, browser, page, problems = open_page(path)
    try:
        page.wait_for_function("window.framesDrawn > 10", timeout=20000)
        page.wait_for_timeout(1000)
        assert not problems, problems
        # pause on one frame, then compare the two figures' pixels
        page.click("#play")
        page.eval_on_selector("#frame", "el => { el.value = 20; el.dispatchEvent(new Event('input')); }")
        drawn = drawn_fraction(page, 0)
        assert drawn > 0.01, drawn  # something is drawn
        differs = canvas_difference(page, 0, 1)
        assert differs > 0.001, differs  # a roll that moves no joint is visible
        shot = Path(os.environ.get("STYLEERD_DEMO_SCREENSHOT") or tmp_path / "demo.png")
        page.screenshot(path=str(shot))
        assert shot.stat().st_size > 10000
    finally:
        browser.close()
        p.stop()


def test_the_demo_writes_a_page_that_plays(tmp_path):
    """``styleerd demo`` end to end: its page loads and draws every motion it lists."""
    from styleerd.eval.demo import run_demo

    run_demo(tmp_path / "demo")
    p, browser, page, problems = open_page(tmp_path / "demo" / "index.html")
    try:
        page.wait_for_function("window.framesDrawn > 10", timeout=30000)
        page.wait_for_timeout(1000)
        assert not problems, problems
        n = page.evaluate("document.querySelectorAll('canvas').length")
        assert n >= 9
        drawn = [drawn_fraction(page, i) for i in range(n)]
        assert min(drawn) > 0.003, drawn
    finally:
        browser.close()
        p.stop()
