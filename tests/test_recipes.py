"""The recipe table and trade-off plot (issue 16) and the ablation table with spreads, from
figures of the shape `evaluate_model` and `runtime_transfers` return."""

import numpy as np
import pytest

from styleerd.errors import StyleERDError
from styleerd.eval.ablations import ABLATIONS
from styleerd.eval.ablations import markdown as ablation_markdown
from styleerd.eval.recipes import markdown, neutralisation, per_style, tradeoff_plot

STYLES = ("active", "elderly", "normal")


def quality(scale: float) -> dict:
    return {
        "transfers": 300,
        "sra": 0.98,
        "cra": 0.9 * scale,
        "content_ceiling": 0.95,
        "fmd": 0.05,
        "fmd_floor": 0.02,
        "fmd_over_floor": 2.5,
        "spread": {"sra": 0.004, "cra": 0.01, "fmd": 0.003},
        "fmd_per_style": {s: 0.05 * (k + 1) for k, s in enumerate(STYLES)},
        "fmd_floor_per_style": {s: 0.02 for s in STYLES},
        "cra_per_style": {s: 0.9 * scale for s in STYLES},
        "content_ceiling_per_style": {s: 0.95 for s in STYLES},
        "sra_per_style": {s: 0.98 for s in STYLES},
        "rec_deg": 7.0,
        "jitter_ratio": 2.0,
        "sra_first_10": 0.9,
        "fmd_first_10": 0.05,
    }


def streamed() -> dict:
    def cell(given, inferred):
        return {"given": {"sra": given, "cra": 0.9}, "inferred": {"sra": inferred, "cra": 0.9}, "windows": 10}

    return {
        "transfers": {
            "active": {"normal": cell(0.9, 0.8)},
            "elderly": {"normal": cell(0.7, 0.6)},
            "normal": {"active": cell(1.0, 1.0), "elderly": cell(0.9, 0.9)},
        }
    }


def test_per_style_ratios_and_neutralisation_summary():
    ps = per_style(quality(1.0))
    assert ps["elderly"] == {"fmd_over_floor": 5.0, "cra_of_ceiling": round(0.9 / 0.95, 4)}
    n = neutralisation(streamed(), "normal")
    assert n["to_neutral"] == {"active": {"given": 0.9, "inferred": 0.8}, "elderly": {"given": 0.7, "inferred": 0.6}}
    assert n["to_neutral_mean"] == {"given": 0.8, "inferred": 0.7} and n["into_styles_mean"] == {
        "given": 0.95,
        "inferred": 0.95,
    }


def test_recipe_table_and_tradeoff_plot(tmp_path):
    rows = {
        name: {
            "model": name,
            "config": name,
            "minutes": 40.0,
            "steps": 1000,
            "quality": quality(s),
            "per_style": per_style(quality(s)),
            "neutralisation": neutralisation(streamed(), "normal"),
            "neutralisation_root_speed": neutralisation(streamed(), "normal"),
        }
        for name, s in (("shipped", 1.0), ("older", 0.95))
    }
    rows["ablation: rec only"] = {
        "model": "a",
        "config": "a",
        "minutes": 40.0,
        "steps": 1000,
        "quality": quality(0.9),
        "per_style": per_style(quality(0.9)),
    }
    text = markdown(rows)
    assert (
        "| shipped | shipped | 40.0 | 1000 | 2.50 (± 0.15) | 94.7 % (± 1.1) |" in text
        and "| 80.0 / 70.0 % | 95.0 / 95.0 % | 80.0 / 70.0 %; 95.0 / 95.0 % |" in text
    )
    assert "| ablation: rec only | a |" in text and text.split("| ablation: rec only |")[1].split("\n")[0].endswith(
        "|  - | - | -  |"
    )
    assert (
        "| back to neutral | 90.0 / 80.0 % | 70.0 / 60.0 % |  |" in text
        and "| into the style, --root-speed | 100.0 / 100.0 % | 90.0 / 90.0 % |  |" in text
    )
    assert "**ablation: rec only** per target style" not in text  # ablations: one row each, no per-style table
    tradeoff_plot(rows, tmp_path / "t.png")
    from PIL import Image

    img = np.asarray(Image.open(tmp_path / "t.png").convert("L"))
    assert img.shape[1] > 1000 and (img < 128).mean() > 0.01  # drawn: axes, points, labels
    many = {f"recipe {i}": rows["shipped"] for i in range(12)}  # more recipes than marker shapes
    tradeoff_plot(many, tmp_path / "many.png")
    assert (tmp_path / "many.png").stat().st_size > 10_000


def test_ablation_table_with_spreads_orders_only_models_at_the_budget():
    rows = {
        name: {"epochs": 40 if k < 3 else 14, **quality(1.0), "fmd": 0.05 + 0.01 * k}
        for k, name in enumerate(ABLATIONS)
    }
    text = ablation_markdown(rows, 40)
    assert (
        "| full |  | 40 | 0.050 ± 0.003 |" in text
        and "Not yet at the full budget (earlier models, kept until theirs are trained; `styleerd eval ablations` "
        "trains them): rec + per, no attention, zero initial states."
        in text
    )
    assert "Ordering by FMD here (models at the full budget): full < rec only < rec + adv." in text
    assert "Ordering in the paper (the same models): full < rec + adv < rec only." in text
    assert (
        "- full 0.050 ± 0.003 vs rec only 0.060 ± 0.003: holds." in text
        and "- full 0.050 ± 0.003 vs rec + adv 0.070 ± 0.003: holds." in text
    )


def test_results_section_from_the_recipe_table_and_the_step_timing(tmp_path):
    import json

    from styleerd.eval.report import recipes_section

    assert recipes_section(tmp_path) == ""  # nothing measured yet: no section
    (tmp_path / "recipes.md").write_text("| model | x |\n| --- | --- |\n| shipped | 1 |\n")
    step = {
        "threads": 2,
        "steps": 40,
        "speedup": 1.67,
        "before": {
            "config": "a.yaml",
            "batch": 32,
            "parts_ms": {"generator forward (B + B)": 30.0, "cycle pass + loss": 40.0},
            "step_ms": 300.0,
            "epoch_s": 120.0,
        },
        "after": {
            "config": "b.yaml",
            "batch": 32,
            "parts_ms": {"generator forward (B + B)": 25.0},
            "step_ms": 180.0,
            "epoch_s": 72.0,
        },
    }
    (tmp_path / "train-step.json").write_text(json.dumps(step))
    text = recipes_section(tmp_path)
    assert "| shipped | 1 |" in text and "(recipes.png)" in text
    assert (
        "| cycle pass + loss | 40.0 | 0.0 |" in text
        and "| step | 300.0 | 180.0 |" in text
        and "1.67 x the training windows per minute" in text
    )
    assert "the trainer's\ncode at the working tree" in text and "kept models' whole runs" not in text
    step["before"] |= {"code": "abc1234", "model": "models/recipes/a", "epochs_trained": 100, "training_min": 200.0}
    step["after"] |= {"model": "models/recipes/b", "epochs_trained": 50, "training_min": 60.0}
    (tmp_path / "train-step.json").write_text(json.dumps({**step, "training_ratio": 0.3}))
    text = recipes_section(tmp_path)
    assert "code at commit abc1234" in text
    assert "`models/recipes/a` 100 epochs, 200.0 min; `models/recipes/b` 50 epochs, 60.0 min: 0.30 of the time." in text


def test_parallel_ablation_trainers_take_different_ablations(tmp_path, monkeypatch):
    import fcntl
    import json

    from styleerd.eval import ablations
    from styleerd.train.config import TrainConfig

    trained = []

    def fake_train(config, out, data_dir, export):
        trained.append(out.name)
        out.mkdir(parents=True, exist_ok=True)
        for suffix in (".safetensors", ".json"):  # a run with the perceptual loss leaves its classifier
            (out / "content_classifier").with_suffix(suffix).write_text("")

    monkeypatch.setattr(
        ablations, "ablation_config", lambda name, threads=1, device="cpu": TrainConfig(**ABLATIONS[name])
    )
    monkeypatch.setattr(ablations, "train", fake_train)
    monkeypatch.setattr(ablations, "ABLATIONS_DIR", tmp_path / "models")
    monkeypatch.setattr(ablations, "shipped_budget", lambda: (TrainConfig(), 40))
    (tmp_path / "models").mkdir()
    for name, epochs in (
        ("no-attention", 14),
        ("zero-initial-states", 40),
    ):  # a shorter model is trained again, one at the budget is not
        (tmp_path / "models" / f"{name}.json").write_text(json.dumps({"training": {"epochs_trained": epochs}}))
    with open(tmp_path / "rec-only.lock", "w") as held:  # another process is training "rec only"
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        stems = ablations.train_ablations(tmp_path)
    assert "rec-only" not in trained and "rec only" not in stems
    assert trained == ["rec-adv", "rec-per", "no-attention"]
    trained.clear()
    ablations.train_ablations(tmp_path)  # the lock released: it is taken up again
    assert trained[0] == "rec-only"


def test_eval_recipes_only_remeasures_the_named_rows_and_keeps_the_others(tmp_path, monkeypatch):
    import json

    from styleerd import cli
    from styleerd.eval import recipes

    def row(name, s):
        return {
            "model": name,
            "config": name,
            "minutes": 40.0,
            "steps": 1000,
            "quality": quality(s),
            "per_style": per_style(quality(s)),
            "neutralisation": neutralisation(streamed(), "normal"),
            "neutralisation_root_speed": neutralisation(streamed(), "normal"),
        }

    monkeypatch.setattr(
        recipes, "recipe_models", lambda: {"shipped": None, "older": tmp_path / "older", "other": tmp_path / "other"}
    )
    monkeypatch.setattr(recipes, "recipe_table", lambda data, names: {n: row(n, 0.97) for n in names})
    out = tmp_path / "recipes.md"
    out.with_suffix(".json").write_text(
        json.dumps({"older": row("older", 0.9), "shipped": row("shipped", 0.9), "gone": row("gone", 0.9)})
    )
    assert cli.main(["eval", "recipes", "--only", "shipped", "--out", str(out)]) in (0, None)
    rows = json.loads(out.with_suffix(".json").read_text())
    assert list(rows) == ["shipped", "older"]  # in the models' order; a model no longer kept is dropped
    assert (
        rows["shipped"]["quality"]["cra"] == quality(0.97)["cra"]
        and rows["older"]["quality"]["cra"] == quality(0.9)["cra"]
    )
    assert out.with_suffix(".png").is_file() and "| older |" in out.read_text()


def test_eval_ablations_only_remeasures_the_named_rows_and_keeps_the_others(tmp_path, monkeypatch):
    import json

    from styleerd import cli
    from styleerd.eval import ablations

    def row(name, fmd):
        return {"recipe": f"ablation-{name}", "epochs": 40, "best_epoch": 30, **quality(1.0), "fmd": fmd}

    evaluated, real_table = [], ablations.ablation_table

    def table(data, names):
        evaluated.append(names)
        return {n: row(n, 0.02) for n in names}

    monkeypatch.setattr(ablations, "ablation_table", table)
    monkeypatch.setattr(ablations, "shipped_budget", lambda: (None, 40))
    out = tmp_path / "ablations.md"
    out.with_suffix(".json").write_text(json.dumps({"rec + adv": row("rec + adv", 0.07), "full": row("full", 0.05)}))
    assert cli.main(["eval", "ablations", "--no-train", "--only", "rec only", "--out", str(out)]) in (0, None)
    rows = json.loads(out.with_suffix(".json").read_text())
    assert evaluated == [["rec only"]] and list(rows) == ["full", "rec only", "rec + adv"]  # the table's order
    assert rows["rec only"]["fmd"] == 0.02 and rows["rec + adv"]["fmd"] == 0.07
    assert "Ordering by FMD here (models at the full budget): rec only < full < rec + adv." in out.read_text()
    with pytest.raises(StyleERDError, match="unknown ablations \\['rec'\\]"):
        real_table(None, ["rec"])


def test_labels_that_would_overlap_are_left_out_the_first_kept():
    """``_label_where_free``: of three labels on one point only the first is written; labels on points far
    apart are all written; one that would leave the axes is not."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from styleerd.eval.recipes import _label_where_free

    fig, ax = plt.subplots()
    ax.set(xlim=(0, 10), ylim=(0, 10))
    _label_where_free(ax, [("first", 5, 5), ("second", 5, 5), ("third", 5.01, 5.01), ("far", 1, 1), ("high", 1, 9.99)])
    assert [t.get_text() for t in ax.texts] == ["first", "far"]
    plt.close(fig)
