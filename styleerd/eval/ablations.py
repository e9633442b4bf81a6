"""The paper's ablation table at the shipped model's budget: the shipped recipe is the full
model, and each ablation removes one part of it, trained with the same data, seed and number
of epochs as the shipped run (so the budget does not depend on what else the machine is
doing), each resumable across sessions, then judged with the same recognisers and FMD
extractor; every figure with its spread over bootstrap resamples of the test windows.

"per" here is the content classifier's supervision: the perceptual loss and, in the shipped
recipe, the content cross-entropy of the same frozen classifier; an ablation without it drops
both. The shipped recipe's cycle loss (transfer and back must give the input) is a
reconstruction loss and stays in every row, "rec only" included."""

from __future__ import annotations

import fcntl
import json
import shutil
from pathlib import Path

from tqdm import tqdm

from styleerd.errors import StyleERDError
from styleerd.model import checkpoint as ckpt
from styleerd.train.config import TrainConfig
from styleerd.train.trainer import train

ABLATIONS = {
    "full": {},
    "rec only": {"use_adv": False, "use_per": False, "w_cls": 0.0},
    "rec + adv": {"use_per": False, "w_cls": 0.0},
    "rec + per": {"use_adv": False},
    "no attention": {"attention": False},
    "zero initial states": {"learned_init": False},
}
CHECKOUT = Path(__file__).resolve().parents[2]
ABLATIONS_DIR = CHECKOUT / "models" / "ablations"  # research runs: in a checkout, not in the package
# the runs' checkpoints, kept in git while they train: a run goes on in the next session (or
# on another machine) where the last one stopped
RUNS_DIR = ABLATIONS_DIR / "training"


def slug(name: str) -> str:
    return name.replace(" + ", "-").replace(" ", "-")


def full_model() -> Path | None:
    """The full model of the paper's table: the shipped model (None), or, when the shipped
    model is a fine-tuning stage beyond the paper (its ``started_from``), the model trained from
    scratch that its stages started from (a path in the checkout, where it was trained)."""
    _, meta = ckpt.load_generator()
    base = meta["training"].get("started_from")
    if base is None:
        return None
    while "started_from" in base["training"]:  # a stage fine-tuned from a stage: its first start
        base = base["training"]["started_from"]
    return CHECKOUT / base["model"]


def shipped_budget() -> tuple[TrainConfig, int]:
    """The full model's training config and the number of epochs its run trained."""
    _, meta = ckpt.load_generator(full_model())
    training = meta["training"]
    return TrainConfig.from_dict(training["config"]), int(training.get("epochs_trained", training["best"]["epoch"]))


def ablation_config(name: str, threads: int = 1, device: str = "cpu") -> TrainConfig:
    base, epochs = shipped_budget()
    return TrainConfig.from_dict(
        {
            **base.to_dict(),
            "name": f"ablation-{slug(name)}",
            "epochs": epochs,
            "max_minutes": 0,
            "threads": threads,
            "device": device,
            **ABLATIONS[name],
        }
    )


def model_stem(name: str) -> Path | None:
    """Where an ablation's model is kept (in git, so tables regenerate without retraining);
    for the full model, ``full_model()``."""
    return full_model() if name == "full" else ABLATIONS_DIR / slug(name)


def trained(name: str) -> bool:
    stem = model_stem(name)
    return stem is None or stem.with_suffix(".safetensors").is_file()


def at_budget(name: str, epochs: int) -> bool:
    """The ablation's kept model was trained the full budget (older, shorter ones are kept in
    the table until theirs are)."""
    stem = model_stem(name)
    if stem is None or not stem.with_suffix(".json").is_file():
        return stem is None
    return int(json.loads(stem.with_suffix(".json").read_text())["training"].get("epochs_trained", 0)) >= epochs


def train_ablations(root: Path, data_dir: str | None = None, threads: int = 1, device: str = "cpu") -> dict[str, Path]:
    """Train (or resume, or skip when its model is at the budget) every ablation in run folders under ``root`` on
    ``device`` and export each best model to ``model_stem(name)``. Several processes may run this at once (one per
    core): each takes the ablations no other process holds (a lock file per run)."""
    stems = {}
    root.mkdir(parents=True, exist_ok=True)
    epochs = shipped_budget()[1]
    for name in tqdm([n for n in ABLATIONS if n != "full"], desc="ablations"):
        if at_budget(name, epochs):
            tqdm.write(f"{name}: its model is trained at the budget ({epochs} epochs), skipped")
            continue
        with open(root / f"{slug(name)}.lock", "w") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                tqdm.write(f"{name}: trained by another process, skipped")
                continue
            out, stem = root / slug(name), model_stem(name)
            config = ablation_config(name, threads, device)
            shared = root / "content_classifier"
            if (
                config.use_per
                and shared.with_suffix(".safetensors").is_file()
                and not (out / "content_classifier.safetensors").is_file()
            ):
                out.mkdir(
                    parents=True, exist_ok=True
                )  # the perceptual classifier is the same for every run: train it once
                for suffix in (".safetensors", ".json"):
                    shutil.copy(shared.with_suffix(suffix), (out / "content_classifier").with_suffix(suffix))
            train(config, out, data_dir, export=stem)
            if config.use_per and not shared.with_suffix(".safetensors").is_file():
                for suffix in (".safetensors", ".json"):
                    shutil.copy((out / "content_classifier").with_suffix(suffix), shared.with_suffix(suffix))
            stems[name] = stem
    return stems


PAPER_FMD = {
    "full": 61.95,
    "rec only": 285.17,
    "rec + adv": 75.40,
    "rec + per": 380.78,
    "no attention": 382.57,
    "zero initial states": 309.70,
}
COLUMNS = [
    ("FMD", "fmd"),
    ("FMD / floor", "fmd_over_floor"),
    ("SRA", "sra"),
    ("CRA", "cra"),
    ("SRA first 10", "sra_first_10"),
    ("FMD first 10", "fmd_first_10"),
    ("rec. deg", "rec_deg"),
    ("jitter", "jitter_ratio"),
]


def ablation_table(data_dir: str | None = None, names: list[str] | None = None) -> dict:
    """Evaluate every trained ablation model (or those of ``names``) with the same judges
    (models not yet trained are left out)."""
    from styleerd.eval.metrics import evaluate_model

    unknown = sorted(set(names or ()) - set(ABLATIONS))
    if unknown:
        raise StyleERDError(f"unknown ablations {unknown}; known: {list(ABLATIONS)}")
    rows = {}
    for name in tqdm([n for n in ABLATIONS if trained(n) and (names is None or n in names)], desc="evaluating"):
        model, meta = ckpt.load_generator(model_stem(name))
        training = meta["training"]
        rows[name] = {
            "recipe": training["config"]["name"],
            "epochs": int(training.get("epochs_trained", training["config"]["epochs"])),
            "best_epoch": training["best"]["epoch"],
            **evaluate_model(model, data_dir),
        }
    return rows


def markdown(rows: dict, epochs: int) -> str:
    spread = {"fmd": "fmd", "fmd_over_floor": "fmd", "sra": "sra", "cra": "cra"}
    head = "| model | trained as | epochs | " + " | ".join(c for c, _ in COLUMNS) + " | paper FMD (Xia) |"
    lines = [head, "|" + " --- |" * (len(COLUMNS) + 4)]

    def cell(r: dict, k: str) -> str:
        if k not in spread:
            return f"{r[k]:.3f}"
        sd = r["spread"][spread[k]] / (r["fmd_floor"] if k == "fmd_over_floor" else 1)
        return f"{r[k]:.3f} ± {sd:.3f}"

    for name, r in rows.items():
        lines.append(
            f"| {name} | {r.get('recipe', '')} | {r['epochs']} | "
            + " | ".join(cell(r, k) for _, k in COLUMNS)
            + f" | {PAPER_FMD[name]:.2f} |"
        )
    missing = [n for n in ABLATIONS if n not in rows]
    at_budget = [n for n, r in rows.items() if r["epochs"] == epochs]
    order = sorted(at_budget, key=lambda n: rows[n]["fmd"])
    paper_order = sorted((n for n in PAPER_FMD if n in at_budget), key=PAPER_FMD.get)
    lines += [
        "",
        f"The full budget: the full model's recipe and data, seed 0, {epochs} epochs (its run's); each model's best",
        "epoch by validation SRA + CRA; all judged on the test split by the shipped recognisers and FMD extractor;",
        "± one standard deviation over 200 bootstrap resamples of the test transfers.",
        f"FMD floor (two halves of the real test windows): {next(iter(rows.values()))['fmd_floor']:.3f}."
        if rows
        else "",
        "",
        f"Ordering by FMD here (models at the full budget): {' < '.join(order)}.",
        f"Ordering in the paper (the same models): {' < '.join(paper_order)}.",
    ]
    if "full" in at_budget and len(at_budget) > 1:
        lines += [
            "",
            "The paper's claim that the full model is the most realistic, ablation by ablation (FMD, ± one spread):",
        ]
        f = rows["full"]
        for name in at_budget:
            if name == "full":
                continue
            r = rows[name]
            gap, spread_sum = r["fmd"] - f["fmd"], r["spread"]["fmd"] + f["spread"]["fmd"]
            verdict = (
                "holds"
                if gap > spread_sum
                else "does not hold"
                if gap < -spread_sum
                else "within the spread (undecided)"
            )
            lines.append(
                f"- full {f['fmd']:.3f} ± {f['spread']['fmd']:.3f} vs {name} {r['fmd']:.3f} ± "
                f"{r['spread']['fmd']:.3f}: {verdict}."
            )
    short = [n for n in rows if n not in at_budget]
    if short:
        lines.append(
            "Not yet at the full budget (earlier models, kept until theirs are trained; `styleerd eval ablations` "
            f"trains them): {', '.join(short)}."
        )
    if missing:
        lines.append(f"Not trained yet (`styleerd eval ablations` resumes them): {', '.join(missing)}.")
    return "\n".join(lines) + "\n"
