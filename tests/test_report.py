"""`styleerd report` regenerates the results page from the shipped models, with the figures
the individual commands print (checked for the deterministic ones)."""

import json

import pytest

from styleerd.eval.ablations import ABLATIONS, trained

pytestmark = pytest.mark.slow


def test_report_regenerates_results_with_the_commands_figures(shared_data, tmp_path):
    from styleerd.eval.metrics import evaluate_model
    from styleerd.eval.report import write_report
    from styleerd.model.checkpoint import load_generator

    assert all(trained(name) for name in ABLATIONS)
    path = write_report(tmp_path, str(shared_data), bench_steps=100, bench_streams=(1, 16), progress=lambda *_: None)
    text = path.read_text()
    q = evaluate_model(load_generator()[0], str(shared_data))
    assert (
        f"| SRA (transfers: neutral -> each style, styled -> neutral; {q['transfers']:,} windows) | "
        f"{100 * q['sra']:.2f} % |" in text
    )
    assert f"{q['fmd']:.3f} ({q['fmd_floor']:.3f})" in text
    ablations = json.loads((tmp_path / "ablations.json").read_text())
    assert list(ablations) == list(ABLATIONS) and "| full |" in text and "paper, GTX 1060" in text
    for picture in (
        "filmstrip-bandai2.png",
        "intensity-bandai2.png",
        "mixture-bandai2.png",
        "first-frames-bandai2.png",
        "throughput.png",
    ):
        assert (tmp_path / picture).stat().st_size > 10_000 and f"({picture})" in text


def test_report_parts_kept_from_their_json_or_measured_and_written(tmp_path):
    import json

    import pytest

    from styleerd.errors import StyleERDError
    from styleerd.eval.report import measured

    with pytest.raises(StyleERDError, match="--keep bench: .* has not been measured yet"):
        measured(tmp_path, "bench", ("bench",), lambda: {"x": 1})
    assert measured(tmp_path, "bench", (), lambda: {"x": 1}) == {"x": 1}
    assert json.loads((tmp_path / "bench.json").read_text()) == {"x": 1}
    assert measured(tmp_path, "bench", ("bench",), lambda: {"x": 2}) == {"x": 1}  # kept: not measured again


def test_the_bench_table_of_a_kept_bench_json():
    """``report --keep bench`` reads docs/bench.json back: its stream counts are then strings."""
    import json
    from pathlib import Path

    from styleerd.eval.bench import table

    text = table(json.loads((Path(__file__).parents[1] / "docs" / "bench.json").read_text()))
    assert "frames/s, 1,000 streams (2 threads)" in text
    numba = list(json.loads((Path(__file__).parents[1] / "docs" / "bench.json").read_text())["backends"]).index("numba")
    row = next(
        line
        for line in text.splitlines()
        if line.startswith("| 1,000 streams (2 threads; each rate the best of 3 windows): fraction of matmul peak |")
    )
    assert row.split(" | ")[1 + numba].endswith(" %")  # issue 18's target, for the backend it was set for


def test_the_added_styles_section_sets_the_critics_side_by_side(tmp_path):
    """docs/unseen-styles.json beside the positions-only critic's run: the paragraph's means are
    the JSONs' own, and without the second file there is no paragraph."""
    import json
    import shutil
    from pathlib import Path

    import numpy as np

    from styleerd.eval.report import added_styles_section

    docs = Path(__file__).parents[1] / "docs"
    shutil.copy(docs / "unseen-styles.json", tmp_path / "unseen-styles.json")
    assert "--critic-positions-only" not in added_styles_section(tmp_path)
    shutil.copy(docs / "unseen-styles-positions-critic.json", tmp_path / "unseen-styles-positions-critic.json")
    text = added_styles_section(tmp_path)
    ours, other = (
        json.loads((tmp_path / name).read_text())["styles"]
        for name in ("unseen-styles.json", "unseen-styles-positions-critic.json")
    )
    fmd = lambda runs: np.mean([v["added"]["fmd"] for v in runs.values()])
    assert f"FMD {fmd(ours):.3f} against {fmd(other):.3f}" in text
    assert "its critic\nread rotations, positions, velocities" in text


def test_filmstrip_writes_an_animated_gif_of_some_styles(shared_data, tmp_path):
    import subprocess
    import sys

    from PIL import Image

    out = tmp_path / "walk.gif"
    cli = [sys.executable, "-m", "styleerd.cli", "filmstrip", "--data", str(shared_data), "-o", str(out)]
    done = subprocess.run(
        [*cli, "--styles", "elderly,feminine"], capture_output=True, text=True, timeout=600, check=False
    )
    assert done.returncode == 0, done.stderr
    with Image.open(out) as gif:
        assert gif.format == "GIF" and gif.n_frames == 60 and gif.size[0] > 2 * gif.size[1]  # 4 s at 15 fps, 3 panels
    wrong = subprocess.run([*cli, "--styles", "sneaky"], capture_output=True, text=True, timeout=600, check=False)
    assert wrong.returncode == 2 and "--styles: the model has no style sneaky" in wrong.stderr


def test_bench_prints_its_table_and_writes_files_only_where_asked(tmp_path, monkeypatch, capsys):
    """``styleerd bench`` run anywhere must not drop docs/ files into the folder it runs in."""
    from pathlib import Path

    from styleerd.cli import main

    kept = json.loads((Path(__file__).parents[1] / "docs" / "bench.json").read_text())
    monkeypatch.setattr("styleerd.eval.bench.run_bench", lambda *a, **k: kept)  # the measuring is not what is tested
    monkeypatch.chdir(tmp_path)
    assert main(["bench"]) == 0
    assert "frames/s, 1,000 streams (2 threads)" in capsys.readouterr().out and not list(tmp_path.iterdir())
    assert main(["bench", "--json", "out/b.json", "--plot", "t.png"]) == 0
    assert json.loads((tmp_path / "out" / "b.json").read_text()) == kept
    assert (tmp_path / "t.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
