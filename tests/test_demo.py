"""`styleerd demo` on a machine without the datasets: the generated input, every style."""

import json
import re
import subprocess
import sys

import numpy as np
from test_transfer import moved_by_the_cleanup_at_most

from styleerd.motion import bvh
from styleerd.motion.procedural import walk


def test_demo_without_data_writes_every_style_and_a_page(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "demo", "--out", str(tmp_path), "--data", str(tmp_path / "no-data")],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    source = bvh.read(tmp_path / "input-walk.bvh")
    assert source.n_frames == walk().n_frames
    outputs = sorted(tmp_path.glob("generated-*.bvh"))
    assert len(outputs) == 8  # 6 styles, half intensity, a mixture
    for path in outputs:
        m = bvh.read(path)
        assert m.skeleton == source.skeleton and m.n_frames == source.n_frames and m.fps == source.fps
        assert (m.positions[:, 0, [0, 2]] == source.positions[:, 0, [0, 2]]).all()  # the input's ground path
        assert moved_by_the_cleanup_at_most(m.positions[:, 0, 1], source.positions[:, 0, 1], source.skeleton)
        assert not np.allclose(m.rotations, source.rotations, atol=1e-3)
    page = (tmp_path / "index.html").read_text()
    data = json.loads(re.search(r"const DATA = (.*?);\n", page).group(1))
    assert len(data["motions"]) == 9 and "generated-elderly.bvh" in r.stdout
