"""The documentation site: `mkdocs build --strict` builds it from docs/ (a broken link, a missing
anchor or an undocumented public function in the API reference fails), and its pages load in
headless Chromium with every picture, stylesheet and script found and nothing fetched from
outside; a screenshot of each is saved."""

import functools
import os
import shutil
import subprocess
import sys
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
PAGES = {  # page -> text its main heading or body must show
    "index.html": "Where to start",
    "guide/transfer/index.html": "Per body part",
    "guide/python/index.html": "Python API",
    "reference/runtime/index.html": "StreamStylizer",
    "RESULTS/index.html": "The shipped model",
}


def build(site: Path, root: Path = ROOT) -> subprocess.CompletedProcess:
    """``mkdocs build --strict`` of the checkout, or of a copy of its docs and package at ``root``."""
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("site")
    done = build(site)
    assert done.returncode == 0, done.stderr
    return site


def test_a_broken_link_or_a_missing_docstring_fails_the_strict_build(tmp_path):
    for part in ("docs", "styleerd", "tools"):
        shutil.copytree(ROOT / part, tmp_path / part, ignore=shutil.ignore_patterns("__pycache__", "vendor"))
    shutil.copy(ROOT / "mkdocs.yml", tmp_path)
    page = tmp_path / "docs/guide/install.md"
    page.write_text(page.read_text() + "\nSee [the missing page](nowhere.md).\n")
    done = build(tmp_path / "site", tmp_path)
    assert done.returncode != 0 and "'nowhere.md'" in done.stderr, done.stderr
    page.write_text(page.read_text().replace("\nSee [the missing page](nowhere.md).\n", ""))
    quat = tmp_path / "styleerd/motion/quat.py"
    documented = quat.read_text()
    assert '    """Identity rotations of the given leading ``shape``: ``[*shape, 4]``."""\n' in documented
    quat.write_text(
        documented.replace('    """Identity rotations of the given leading ``shape``: ``[*shape, 4]``."""\n', "")
    )
    done = build(tmp_path / "site", tmp_path)
    assert done.returncode != 0 and "styleerd.motion.quat.identity has no docstring" in done.stderr, done.stderr
    quat.write_text(documented)
    assert build(tmp_path / "site", tmp_path).returncode == 0  # the copy itself builds


@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="Chromium not installed (.ci/run installs Debian's chromium)")
def test_the_pages_load_in_chromium_with_everything_they_need(site, tmp_path):
    from playwright.sync_api import sync_playwright

    class Quiet(SimpleHTTPRequestHandler):
        def log_message(self, *args) -> None:
            pass

    handler = functools.partial(Quiet, directory=str(site))
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}/"
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox", "--disable-gpu"])
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            failed, outside, errors = [], [], []
            page.on("requestfailed", lambda r: failed.append(r.url))
            page.on("response", lambda r: r.status >= 400 and failed.append(f"{r.status} {r.url}"))
            page.on("request", lambda r: r.url.startswith(("http://", "https://")) and not r.url.startswith(base)
                    and outside.append(r.url))  # fmt: skip
            page.on("pageerror", lambda e: errors.append(str(e)))
            for path, text in PAGES.items():
                page.goto(base + path, wait_until="networkidle")
                assert text in page.inner_text("article"), path
                broken = page.evaluate(
                    "[...document.images].filter(i => !i.complete || !i.naturalWidth).map(i => i.src)"
                )
                assert not broken, (path, broken)
                page.screenshot(path=str(tmp_path / (path.replace("/", "_") + ".png")))
            nav = page.inner_text("nav.md-nav--primary")
            assert all(title in nav for title in ("User guide", "API reference", "Evaluation and benchmarks"))
            browser.close()
    finally:
        server.shutdown()
    assert not failed and not outside and not errors, (failed, outside, errors)
