"""The paper's ablation table: the full model and five ablations, trained with the same data,
seed and budget (a number of epochs, so the budget does not depend on what else the machine
is doing), each resumable, then evaluated with the same recognisers and FMD extractor."""

from __future__ import annotations

import shutil
from pathlib import Path

from tqdm import tqdm

from styleerd.train.config import TrainConfig
from styleerd.train.trainer import train

ABLATIONS = {
    "full": {},
    "rec only": {"use_adv": False, "use_per": False},
    "rec + adv": {"use_per": False},
    "rec + per": {"use_adv": False},
    "no attention": {"attention": False},
    "zero initial states": {"learned_init": False},
}
BASE_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "bandai2.yaml"
ABLATIONS_DIR = Path(__file__).resolve().parents[2] / "models" / "ablations"  # research runs: in a checkout, not in the package


def slug(name: str) -> str:
    return name.replace(" + ", "-").replace(" ", "-")


def ablation_config(name: str, epochs: int, threads: int = 1) -> TrainConfig:
    return TrainConfig.from_yaml(BASE_CONFIG, name=f"ablation-{slug(name)}", epochs=epochs, max_minutes=0, threads=threads, **ABLATIONS[name])


def model_stem(name: str) -> Path:
    """Where an ablation's model is kept (in git, so tables regenerate without retraining)."""
    return ABLATIONS_DIR / slug(name)


def train_ablations(root: Path, epochs: int, data_dir: str | None = None, threads: int = 1) -> dict[str, Path]:
    """Train (or resume, or skip when finished) every ablation in run folders under ``root``
    and export each best model to ``model_stem(name)``."""
    stems = {}
    for name in tqdm(ABLATIONS, desc="ablations"):
        out = root / slug(name)
        stem = model_stem(name)
        config = ablation_config(name, epochs, threads)
        shared = root / "content_classifier"
        if config.use_per and shared.with_suffix(".safetensors").is_file() and not (out / "content_classifier.safetensors").is_file():
            out.mkdir(parents=True, exist_ok=True)  # the perceptual classifier is the same for every run: train it once
            for suffix in (".safetensors", ".json"):
                shutil.copy(shared.with_suffix(suffix), (out / "content_classifier").with_suffix(suffix))
        train(config, out, data_dir, export=stem)
        if config.use_per and not shared.with_suffix(".safetensors").is_file():
            for suffix in (".safetensors", ".json"):
                shutil.copy((out / "content_classifier").with_suffix(suffix), shared.with_suffix(suffix))
        stems[name] = stem
    return stems


PAPER_FMD = {"full": 61.95, "rec only": 285.17, "rec + adv": 75.40, "rec + per": 380.78, "no attention": 382.57, "zero initial states": 309.70}
COLUMNS = [
    ("FMD", "fmd"), ("FMD / floor", "fmd_over_floor"), ("SRA", "sra"), ("CRA", "cra"),
    ("SRA first 10", "sra_first_10"), ("FMD first 10", "fmd_first_10"), ("rec. deg", "rec_deg"), ("jitter", "jitter_ratio"),
]  # fmt: skip


def ablation_table(data_dir: str | None = None) -> dict:
    """Evaluate every exported ablation model with the same judges."""
    from styleerd.eval.metrics import evaluate_model
    from styleerd.model.checkpoint import load_generator

    rows = {}
    for name in tqdm(ABLATIONS, desc="evaluating"):
        model, meta = load_generator(model_stem(name))
        rows[name] = {"epochs": meta["training"]["best"]["epoch"], **evaluate_model(model, data_dir)}
    return rows


def markdown(rows: dict, epochs: int) -> str:
    head = "| model | " + " | ".join(c for c, _ in COLUMNS) + " | paper FMD (Xia) |"
    lines = [head, "|" + " --- |" * (len(COLUMNS) + 2)]
    for name, r in rows.items():
        lines.append(f"| {name} | " + " | ".join(f"{r[k]:.3f}" if isinstance(r[k], float) else str(r[k]) for _, k in COLUMNS) + f" | {PAPER_FMD[name]:.2f} |")
    order = sorted(rows, key=lambda n: rows[n]["fmd"])
    paper_order = sorted(PAPER_FMD, key=PAPER_FMD.get)
    lines += [
        "",
        f"Every model: Bandai-Namco-2, seed 0, {epochs} epochs (batch 32; the shipped model trains 80 min, about 130 epochs),",
        "best epoch by validation SRA + CRA; judged on the test split by the shipped recognisers and FMD extractor.",
        f"FMD floor (two halves of the real test windows): {rows[order[0]]['fmd_floor']:.3f}.",
        "",
        f"Ordering by FMD here: {' < '.join(order)}.",
        f"Ordering in the paper: {' < '.join(paper_order)}.",
    ]
    return "\n".join(lines) + "\n"
