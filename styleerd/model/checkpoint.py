"""Models on disk: ``NAME.safetensors`` (weights) + ``NAME.json`` (everything else: config,
skeleton, labels, feature statistics, training config, code version, data checksum).
No pickle anywhere; both files are written atomically."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file
from torch import nn

from styleerd.data.features import FeatureStats
from styleerd.errors import StyleERDError
from styleerd.model.classifiers import WindowClassifier
from styleerd.model.generator import GeneratorConfig, StyleERD
from styleerd.motion.skeleton import Skeleton

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
DEFAULT_MODEL = "styleerd-bandai2"
RECOGNISERS = "recognisers-bandai2"


def _atomic(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def save_tensors(stem: Path, tensors: dict[str, torch.Tensor], meta: dict) -> None:
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    _atomic(stem.with_suffix(".safetensors"), lambda p: save_file(tensors, p))
    _atomic(stem.with_suffix(".json"), lambda p: Path(p).write_text(json.dumps(meta, indent=1)))


def load_tensors(stem: Path) -> tuple[dict[str, torch.Tensor], dict]:
    stem = Path(stem)
    try:
        meta = json.loads(stem.with_suffix(".json").read_text())
        tensors = load_file(stem.with_suffix(".safetensors"))
    except (OSError, ValueError) as e:
        raise StyleERDError(f"cannot load model {stem}: {e}") from None
    return tensors, meta


def prefixed(prefix: str, module: nn.Module) -> dict[str, torch.Tensor]:
    return {f"{prefix}.{k}": v for k, v in module.state_dict().items()}


def unprefixed(prefix: str, tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k[len(prefix) + 1 :]: v for k, v in tensors.items() if k.startswith(prefix + ".")}


def generator_meta(model: StyleERD, skeleton: Skeleton, stats: FeatureStats, **extra) -> dict:
    return {"kind": "styleerd-generator", "config": model.config.to_dict(), "skeleton": skeleton.to_dict(), "stats": stats.to_dict(), **extra}


def build_generator(meta: dict) -> StyleERD:
    return StyleERD(GeneratorConfig.from_dict(meta["config"]), Skeleton.from_dict(meta["skeleton"]), FeatureStats.from_dict(meta["stats"]))


def load_generator(stem: str | Path | None = None) -> tuple[StyleERD, dict]:
    """The generator saved at ``stem`` (default: the shipped model), in eval mode."""
    tensors, meta = load_tensors(Path(stem) if stem else MODELS_DIR / DEFAULT_MODEL)
    model = build_generator(meta)
    model.load_state_dict(unprefixed("generator", tensors))
    return model.eval(), meta


def classifier_meta(model: WindowClassifier, labels: list[str], **extra) -> dict:
    return {"in_dim": model.in_dim, "labels": labels, "channels": list(model.channels), "kernel": model.kernel, "instance_norm": model.instance_norm, **extra}


def build_classifier(meta: dict) -> WindowClassifier:
    return WindowClassifier(meta["in_dim"], len(meta["labels"]), tuple(meta["channels"]), meta["kernel"], meta["instance_norm"])


def load_recognisers(stem: str | Path | None = None) -> tuple[WindowClassifier, WindowClassifier, dict]:
    """(style recogniser, content recogniser, meta) for evaluation."""
    tensors, meta = load_tensors(Path(stem) if stem else MODELS_DIR / RECOGNISERS)
    style = build_classifier(meta["style"])
    style.load_state_dict(unprefixed("style", tensors))
    content = build_classifier(meta["content"])
    content.load_state_dict(unprefixed("content", tensors))
    return style.eval(), content.eval(), meta
