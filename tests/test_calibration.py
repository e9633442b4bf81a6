"""The numba step's settings measured per machine (``runtime.calibration``): every path it may
choose steps as the numpy backend does, the choice is the fastest it timed, and it is cached by
machine, libraries and model shape (read back, not measured again; measured again when the file
is damaged or was written for another machine)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from styleerd.model.stored import load_generator_weights
from styleerd.runtime import calibration
from styleerd.runtime.backends import make_backend
from styleerd.runtime.calibration import EngineSettings, StepChoice, candidates, engine_settings, fixed_settings
from styleerd.runtime.compiled import CompiledBackend


@pytest.fixture(scope="module")
def model():
    return load_generator_weights()


@pytest.mark.parametrize("n", [1, 5, 8, 40, 300])
def test_every_path_the_calibration_may_choose_steps_as_the_numpy_backend(model, n):
    c = model.config
    rng = np.random.default_rng(n)
    style = np.eye(len(c.input_styles), dtype=np.float32)[rng.integers(0, len(c.input_styles), n)]
    content = np.eye(len(c.contents), dtype=np.float32)[rng.integers(0, len(c.contents), n)]
    target = rng.dirichlet(np.ones(len(c.styles)) * 0.3, n).astype(np.float32)  # mixtures: every branch runs
    x = rng.normal(0, 1, (5, n, c.feature_dim)).astype(np.float32)
    ref = make_backend("numpy", model, n)
    want = [ref.step(x[t], style, content, target) for t in range(len(x))]
    options = candidates(n, 2)
    assert {o.loops for o in options} == ({True, False} if n <= 8 else {False})
    for choice in options:
        fast = CompiledBackend(model, n, 2, EngineSettings((1,), (choice,), (choice,), "test"))
        for t in range(len(x)):
            rot, vel = fast.step(x[t], style, content, target)
            assert np.abs(rot - want[t][0]).max() <= 1e-5 and np.abs(vel - want[t][1]).max() <= 1e-4, (choice, t)


def test_the_choice_for_a_batch_is_the_one_calibrated_at_or_below_it():
    one = tuple(StepChoice(b, False, 1) for b in (1, 2, 3))
    many = tuple(StepChoice(b, False, 2) for b in (1, 2, 3))
    s = EngineSettings((1, 16, 256), one, many, "test")
    assert s.choice(0, 1) == one[0] and s.choice(15, 1) == one[0] and s.choice(16, 1) == one[1]
    assert s.choice(10_000, 1) == one[2] and s.choice(255, 4) == many[1] and s.choice(256, 2) == many[2]
    fixed = fixed_settings(2)  # today's constants: loops for 1 stream, BLAS blocks of 32, threads from 32
    assert fixed.choice(1, 2) == StepChoice(32, True, 1) and fixed.choice(31, 2) == StepChoice(32, False, 1)
    assert fixed.choice(32, 2) == StepChoice(32, False, 2) and fixed.choice(5000, 1).threads == 1


def test_a_choice_that_took_the_whole_shard_takes_it_whole_at_the_sizes_it_stands_for(tmp_path):
    """Calibrated at 32 streams, blocks of 32 (the whole shard) beat blocks of 16: at 39 streams the
    step takes one block of 39, not 32 and 7. Where a smaller block won (512 of 1,024 streams on one
    thread), it stays; on two threads a shard is half the streams."""
    row = lambda n, one, many: {
        "streams": n,
        "one_thread": {"block_rows": one, "loops": False, "threads": 1},
        "many_threads": {"block_rows": many, "loops": False, "threads": 2},
    }
    record = {"seconds": 1.0, "choices": [row(32, 32, 16), row(1024, 512, 256)]}
    settings = calibration.settings_from(record, tmp_path / "calibration.json")
    assert (
        settings.choice(39, 1).block_rows == calibration.WHOLE
        and settings.choice(39, 2).block_rows == calibration.WHOLE
    )
    assert settings.choice(2000, 1).block_rows == 512 and settings.choice(2000, 2).block_rows == 256
    model = load_generator_weights()
    c, n = model.config, 39
    rng = np.random.default_rng(39)
    style = np.eye(len(c.input_styles), dtype=np.float32)[rng.integers(0, len(c.input_styles), n)]
    content = np.eye(len(c.contents), dtype=np.float32)[rng.integers(0, len(c.contents), n)]
    target = rng.dirichlet(np.ones(len(c.styles)) * 0.3, n).astype(np.float32)
    x = rng.normal(0, 1, (n, c.feature_dim)).astype(np.float32)
    want = make_backend("numpy", model, n).step(x, style, content, target)
    got = CompiledBackend(model, n, 2, settings).step(x, style, content, target)  # one whole block on each thread
    assert np.abs(got[0] - want[0]).max() <= 1e-5 and np.abs(got[1] - want[1]).max() <= 1e-4


def test_calibration_is_cached_by_machine_and_model_shape(model, tmp_path, monkeypatch):
    monkeypatch.setenv("STYLEERD_CACHE", str(tmp_path))
    monkeypatch.setattr(calibration, "CONTENDED", float("inf"))  # a busy test machine's calibration is kept too
    monkeypatch.setattr(calibration, "STREAMS", (1, 4, 40))
    monkeypatch.setattr(calibration, "ROUNDS", 1)
    monkeypatch.setattr(calibration, "_known", {})
    measured = []
    real = calibration.calibrate
    monkeypatch.setattr(calibration, "calibrate", lambda *a, **k: measured.append(1) or real(*a, **k))

    first = engine_settings(model)
    (path,) = (tmp_path / "engine").glob("calibration-*.json")
    record = json.loads(path.read_text())
    assert measured == [1] and record["key"] == calibration.machine_key(model) and str(path) in first.source
    for row in record["choices"]:  # the fastest timed, among the candidates of its size
        timed = {(t["block_rows"], t["loops"], t["threads"]): t["us_per_step"] for t in row["timed"]}
        assert set(timed) == {(c.block_rows, c.loops, c.threads) for c in candidates(row["streams"], record["threads"])}
        many, one = row["many_threads"], row["one_thread"]
        assert many["us_per_step"] == min(timed.values())
        assert one["threads"] == 1 and one["us_per_step"] == min(v for k, v in timed.items() if k[2] == 1)

    monkeypatch.setattr(calibration, "_known", {})  # another process: read back, not measured
    assert engine_settings(model) == first and measured == [1]
    path.write_text(path.read_text()[:-20])  # damaged: measured again, and whole again
    monkeypatch.setattr(calibration, "_known", {})
    engine_settings(model)
    assert measured == [1, 1] and json.loads(path.read_text())["key"] == record["key"]
    path.write_text(json.dumps(record | {"key": record["key"] | {"cpu": "another CPU"}}))  # another machine's
    monkeypatch.setattr(calibration, "_known", {})
    engine_settings(model)
    assert measured == [1, 1, 1]

    monkeypatch.setenv("STYLEERD_CALIBRATE", "0")
    assert engine_settings(model) == fixed_settings()


def busy_rows(slow_from: int) -> list[dict]:
    """Calibration rows (``calibrate``'s) of a step that takes 10 us a stream on one thread and
    half that on two, except from ``slow_from`` streams on, where a step on two threads waits 8 ms
    for a core another process holds."""
    rows = []
    for n in (1, 8, 64):
        one, two = 10.0 * n, 5.0 * n + (8000.0 if n >= slow_from else 0.0)
        timed = [{"block_rows": n, "loops": False, "threads": 1, "us_per_step": one, "steps": 10}]
        timed += (
            [{"block_rows": n // 2, "loops": False, "threads": 2, "us_per_step": two, "steps": 10}] if n > 1 else []
        )
        best = min(timed, key=lambda t: t["us_per_step"])
        rows.append({"streams": n, "one_thread": timed[0], "many_threads": best, "timed": timed})
    return rows


def test_a_calibration_made_while_another_process_held_a_core_is_not_kept(model, tmp_path, monkeypatch):
    """Steps on two threads many times slower than on one are another process's doing: such a
    calibration holds for its own process only (one thread from there on, its source says why), and
    a cached one that shows it, as an earlier version wrote, is measured again."""
    assert calibration.contention(busy_rows(10**6)) is None
    assert calibration.contention(busy_rows(8)) == {"streams": 8, "one_thread_us": 80.0, "threads_us": 8040.0}
    monkeypatch.setenv("STYLEERD_CACHE", str(tmp_path))
    monkeypatch.setattr(calibration, "STREAMS", (1, 8, 64))
    monkeypatch.setattr(calibration, "ROUNDS", 1)
    monkeypatch.setattr(calibration, "_known", {})
    real_timer = calibration._timer

    def busy_timer(model, n, threads):  # the second core is another process's from 8 streams on
        time_steps = real_timer(model, n, threads)
        return lambda choice: [t + (0.008 if choice.threads > 1 and n >= 8 else 0.0) for t in time_steps(choice)]

    monkeypatch.setattr(calibration, "_timer", busy_timer)
    settings = engine_settings(model)
    assert not (tmp_path / "engine").exists() or not list((tmp_path / "engine").glob("*.json"))  # not kept
    assert "another process held a core" in settings.source and "at 8 streams" in settings.source
    assert settings.choice(64, 2).threads == 1 and settings.choice(8, 2).threads == 1
    monkeypatch.setattr(calibration, "_timer", real_timer)
    key = calibration.machine_key(model)
    path = calibration.cache_path(key)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"format": 1, "key": key, "threads": 2, "seconds": 30.0, "choices": busy_rows(8)}))
    monkeypatch.setattr(calibration, "_known", {})
    measured = []
    real = calibration.calibrate

    def quiet(*a, **k):  # the machine is quiet now (a busy test machine's timings taken as quiet)
        measured.append(1)
        with monkeypatch.context() as m:
            m.setattr(calibration, "CONTENDED", float("inf"))
            return real(*a, **k)

    monkeypatch.setattr(calibration, "calibrate", quiet)
    assert str(path) in engine_settings(model).source  # measured again, and kept
    assert measured == [1] and json.loads(path.read_text())["contended"] is None
