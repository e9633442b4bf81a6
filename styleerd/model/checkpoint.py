"""Models on disk as torch modules (training and evaluation): ``NAME.safetensors`` (weights) +
``NAME.json`` (everything else: config, skeleton, labels, feature statistics, training config,
code version, data checksum). No pickle anywhere; both files are written atomically. Reading
without torch, and where models are found: ``model.stored``."""

from __future__ import annotations

import json
from pathlib import Path

import torch
from safetensors.torch import save_file
from torch import nn

from styleerd.atomic import atomic_write, atomic_write_text
from styleerd.data.features import FeatureStats
from styleerd.model.classifiers import WindowClassifier
from styleerd.model.config import GeneratorConfig
from styleerd.model.fmd import MotionAutoencoder
from styleerd.model.generator import StyleERD
from styleerd.model.labeller import OnlineLabeller
from styleerd.model.stored import (
    Familiarity,
    GeneratorWeights,
    familiar_range,
    load_arrays,
    loaded,
    posture_frame,
    posture_offsets,
    posture_vectors,
)
from styleerd.models import DEFAULT_MODEL, FMD, LABELLER, RECOGNISERS
from styleerd.motion.skeleton import Skeleton


def save_tensors(stem: Path, tensors: dict[str, torch.Tensor], meta: dict, sidecar: bool = True) -> None:
    """Weights to ``stem.safetensors`` with ``meta`` embedded in its header (one atomic file),
    and, with ``sidecar``, the same meta as readable ``stem.json``."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    text = json.dumps(meta, indent=1)
    atomic_write(stem.with_suffix(".safetensors"), lambda p: save_file(tensors, p, metadata={"styleerd": text}))
    if sidecar:
        atomic_write_text(stem.with_suffix(".json"), text + "\n")


def load_tensors(stem: Path) -> tuple[dict[str, torch.Tensor], dict]:
    arrays, meta = load_arrays(stem)
    return {k: torch.from_numpy(v) for k, v in arrays.items()}, meta


def _loaded(name: str | Path | None, default: str, build):
    """``loaded`` (model.stored) with the weights as torch tensors."""
    return loaded(name, default, lambda arrays, meta: build({k: torch.from_numpy(v) for k, v in arrays.items()}, meta))


def prefixed(prefix: str, module: nn.Module) -> dict[str, torch.Tensor]:
    return {f"{prefix}.{k}": v for k, v in module.state_dict().items()}


def unprefixed(prefix: str, tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k[len(prefix) + 1 :]: v for k, v in tensors.items() if k.startswith(prefix + ".")}


def generator_meta(model: StyleERD, skeleton: Skeleton, stats: FeatureStats, **extra) -> dict:
    return {
        "kind": "styleerd-generator",
        "config": model.config.to_dict(),
        "skeleton": skeleton.to_dict(),
        "stats": stats.to_dict(),
        **extra,
    }


def build_generator(meta: dict) -> StyleERD:
    config = GeneratorConfig.from_dict(meta["config"])
    model = StyleERD(config, Skeleton.from_dict(meta["skeleton"]), FeatureStats.from_dict(meta["stats"]))
    posture, offsets = posture_vectors(meta, config), posture_offsets(meta, config)
    model.posture = None if posture is None else torch.from_numpy(posture).float()
    model.posture_offsets = None if offsets is None else torch.from_numpy(offsets).float()
    model.posture_frame = posture_frame(meta)
    model.familiar = familiar_range(meta)
    return model


def torch_generator(weights: GeneratorWeights) -> StyleERD:
    """The torch module of generator weights read without torch (``model.stored``)."""
    model = StyleERD(weights.config, weights.skeleton, weights.stats())
    model.load_state_dict({k: torch.from_numpy(v) for k, v in weights.arrays.items()})
    model.posture = None if weights.posture is None else torch.from_numpy(weights.posture).float()
    offsets = weights.posture_offsets
    model.posture_offsets = None if offsets is None else torch.from_numpy(offsets).float()
    model.posture_frame = weights.posture_frame
    model.familiar = weights.familiar
    return model.eval()


def load_generator(stem: str | Path | None = None) -> tuple[StyleERD, dict]:
    """The generator saved at ``stem`` (default: the shipped model), in eval mode."""

    def build(tensors, meta):
        model = build_generator(meta)
        model.load_state_dict(unprefixed("generator", tensors))
        return model.eval()

    return _loaded(stem, DEFAULT_MODEL, build)


def classifier_meta(model: WindowClassifier, labels: list[str], **extra) -> dict:
    return {
        "in_dim": model.in_dim,
        "first_channel": model.first_channel,
        "labels": labels,
        "channels": list(model.channels),
        "kernel": model.kernel,
        "instance_norm": model.instance_norm,
        **extra,
    }


def build_classifier(meta: dict) -> WindowClassifier:
    return WindowClassifier(
        meta["in_dim"],
        len(meta["labels"]),
        tuple(meta["channels"]),
        meta["kernel"],
        meta["instance_norm"],
        meta.get("first_channel", 0),
    )


def load_recognisers(stem: str | Path | None = None) -> tuple[WindowClassifier, WindowClassifier, dict]:
    """(style recogniser, content recogniser, meta) for evaluation."""

    def build(tensors, meta):
        style, content = build_classifier(meta["style"]), build_classifier(meta["content"])
        style.load_state_dict(unprefixed("style", tensors))
        content.load_state_dict(unprefixed("content", tensors))
        return style.eval(), content.eval()

    (style, content), meta = _loaded(stem, RECOGNISERS, build)
    return style, content, meta


def load_labeller(stem: str | Path | None = None) -> tuple[OnlineLabeller, dict]:
    """The online style/content labeller saved at ``stem`` (default: the shipped one)."""

    def build(tensors, meta):
        model = OnlineLabeller(**meta["config"])
        model.load_state_dict(unprefixed("labeller", tensors))
        arrays = {k: v.numpy() for k, v in tensors.items()}
        model.familiar = Familiarity.from_arrays(arrays, model.hidden, model.n_styles)
        return model.eval()

    return _loaded(stem, LABELLER, build)


def load_fmd(stem: str | Path | None = None) -> tuple[MotionAutoencoder, dict]:
    """The FMD feature extractor saved at ``stem`` (default: the shipped one)."""

    def build(tensors, meta):
        c = meta["config"]
        model = MotionAutoencoder(c["n_joints"], tuple(c["channels"]), c["kernel"])
        model.load_state_dict(unprefixed("autoencoder", tensors))
        return model.eval()

    return _loaded(stem, FMD, build)
