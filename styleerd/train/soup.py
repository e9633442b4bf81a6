"""A model soup (Wortsman et al. 2022): one generator whose weights are the weighted average of
the weights of generators fine-tuned from the same start. Models fine-tuned from one start
differently (here: a second stage on its last weights and one on their moving average) stay in
one basin of the loss, so their average is a model too, often better than each; it costs no
training and nothing at inference."""

from __future__ import annotations

from pathlib import Path

import torch

from styleerd.errors import StyleERDError
from styleerd.model import checkpoint as ckpt


def averaged(states: list[dict[str, torch.Tensor]], weights: list[float]) -> dict[str, torch.Tensor]:
    """The generators' state dicts ``states`` averaged with ``weights``, as a model file's tensors
    (float64 sums: tensors they share come back exact)."""
    return {f"generator.{k}": sum(w * s[k].double() for w, s in zip(weights, states)).float() for k in states[0]}


def soup(stems: list[str], weights: list[float] | None = None) -> tuple[dict[str, torch.Tensor], dict]:
    """The averaged generator's tensors and metadata: ``weights`` (default equal) sum to 1;
    every model must share the first's architecture, skeleton, feature statistics and start."""
    if len(stems) < 2:
        raise StyleERDError("a soup needs at least two models")
    weights = weights or [1.0 / len(stems)] * len(stems)
    if len(weights) != len(stems) or min(weights) < 0 or abs(sum(weights) - 1.0) > 1e-6:
        raise StyleERDError(f"weights {weights}: one per model, none negative, summing to 1")
    loaded = [ckpt.load_generator(s) for s in stems]
    (first, meta), start = loaded[0], loaded[0][1]["training"].get("started_from", {}).get("model")
    if start is None:
        raise StyleERDError(
            f"{stems[0]} was not fine-tuned from a saved model: only models with one start average into a model"
        )
    for stem, (model, m) in zip(stems[1:], loaded[1:]):
        if (
            model.config.to_dict() != first.config.to_dict()
            or m["skeleton"] != meta["skeleton"]
            or m["stats"] != meta["stats"]
        ):
            raise StyleERDError(
                f"{stem}: its generator (config, skeleton or feature statistics) differs from {stems[0]}'s"
            )
        if m["training"].get("started_from", {}).get("model") != start:
            raise StyleERDError(
                f"{stem} was not fine-tuned from {start}, as {stems[0]} was: their weights do not average into a model"
            )
    tensors = averaged([model.state_dict() for model, _ in loaded], weights)
    stages = [
        {"model": str(stem), "weight": w, "training": m["training"]} for stem, w, (_, m) in zip(stems, weights, loaded)
    ]
    names = " + ".join(f"{w:g} {Path(stem).name}" for stem, w in zip(stems, weights))
    training = {
        "config": {**meta["training"]["config"], "name": f"soup: {names}"},
        "kept": f"the weighted average of {len(stems)} models' weights ({names}), each fine-tuned from {start}",
        "soup": stages,
        # the stages' training, one after the other (they are independent runs from one start:
        # side by side, one per core, they take about the longest one's time)
        "wall_minutes": round(sum(s["training"].get("wall_minutes") or 0.0 for s in stages), 2),
        "epochs_trained": meta["training"].get("epochs_trained"),
        "started_from": meta["training"]["started_from"],
    }
    # the posture and the familiar range were measured on one model, not on the average: the posture is kept
    # as the first model's (nearer the soup's than none) and says so, the range is dropped for the default;
    # ``styleerd posture`` and ``styleerd familiar`` measure the soup's own
    kept = {k: v for k, v in meta.items() if k != "familiar"}
    if "posture" in kept:
        first_posture = f"{stems[0]}'s (the soup's first model): {kept['posture']['measured_on']}"
        kept["posture"] = {**kept["posture"], "measured_on": first_posture}
    return tensors, {**kept, "training": training}


def save_soup(stems: list[str], out: Path, weights: list[float] | None = None) -> dict:
    tensors, meta = soup(stems, weights)
    ckpt.save_tensors(Path(out), tensors, meta)
    return meta
