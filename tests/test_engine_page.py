"""The step in the browser (static/engine.html): onnxruntime-web, vendored from npm, runs the
exported LSTM-op graph in real Chromium with the page's own feature code, and its output equals
the server's stylisation of the same clip; no console errors, something drawn; the per-frame
time is reported."""

import json
from pathlib import Path

import numpy as np
import pytest
from test_viewer import CHROMIUM, chromium_page

from styleerd.serve.loadtest import free_port, start_server, stop_server

pytestmark = pytest.mark.skipif(
    not Path(CHROMIUM).exists(), reason="Chromium not installed (.ci/run installs Debian's chromium)"
)


@pytest.mark.parametrize("style, clip", [("elderly", "walk"), ("feminine", "walk"), ("active", "guard")])
def test_the_browser_step_equals_the_server_and_draws(style, clip, tmp_path):
    """The guard into active: a posture that raises the hands past the eyes, whose rise is cut."""
    port = free_port()
    server = start_server(port)
    try:
        url = f"http://127.0.0.1:{port}/static/engine.html?style={style}&clip={clip}"
        with chromium_page(url, 1000, 500, console=True) as (page, errors):
            page.wait_for_function("window.result !== undefined", timeout=120000)
            result = page.evaluate("window.result")
            pixels = np.frombuffer(page.locator("#view").screenshot(path=str(tmp_path / "engine.png")), np.uint8)
            drawn = page.evaluate("""() => {
                const c = document.getElementById('view');
                const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
                let n = 0; for (let i = 0; i < d.length; i += 4) if (d[i] > 150 && d[i + 1] < 100) n++; return n; }""")
    finally:
        assert stop_server(server) == 0
    assert not errors, errors
    assert "error" not in result, result
    assert result["frames"] == 120 and result["style"] == style and result["clip"] == clip
    assert result["max_abs_difference"] <= 1e-4, result
    assert drawn > 500 and len(pixels)  # red stick figures on the canvas
    print(json.dumps(result))  # the per-frame time in the browser (pytest -s shows it)
