"""Training configuration: one plain dataclass, read from YAML (``configs/*.yaml``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from pathlib import Path

import yaml

from styleerd.errors import StyleERDError


@dataclass
class TrainConfig:
    name: str = "styleerd"
    dataset: str = "bandai-namco-2"
    neutral_style: str = "normal"
    window: int = 24
    stride: int = 20  # between training windows (24 - 4 frames of overlap, as in the paper)
    max_train_clips: int = 0  # 0 = all; small values make tiny test runs
    balance_styles: bool = False  # styled windows drawn style by style (styles with few clips get their share)
    seed: int = 0
    threads: int = 2
    device: str = "cpu"  # where the networks train ("cuda" on a GPU); validation and the saved weights stay on the CPU
    # generator
    encoder: tuple[int, ...] = (64, 32)
    hidden: int = 32
    neutral_layers: int = 6
    style_layers: int = 4
    decoder: tuple[int, ...] = (58, 86, 128)
    learned_init: bool = True
    # the decoder outputs each joint's change to the input's rotation (``GeneratorConfig.pose_change``); fine-tuned
    # from a model without it, the decoder's rotation outputs start at no change
    pose_change: bool = False
    # supervision (ablation switches: rec only = use_adv False + use_per False)
    use_adv: bool = True
    use_per: bool = True
    attention: bool = True
    critic_rotations: bool = (
        False  # the critic also sees joint rotations (their twist is invisible in positions), beyond the paper
    )
    w_rec: float = 1.0
    w_adv: float = 1.0
    w_per: float = 0.1
    w_gp: float = 128.0
    w_cyc: float = 0.0  # cycle reconstruction (transfer and back), beyond the paper; 0 = off
    cyc_every: int = 1  # lazy cycle: on every k-th step only, weighted by k (it is a third generator pass)
    w_cls: float = 0.0  # content cross-entropy of the perceptual classifier on transfers, beyond the paper; 0 = off
    r1_every: int = 4  # lazy R1: every k critic steps, weighted by k
    # > 0: every step also rebuilds this many windows of other performers' clips (kicks, dances, climbing) and of
    # training walks in place (``train.batches.outside_windows``) in their own style, told a random content, so that
    # poses the training data lacks pass through and no content label is needed; that loss weighs ``w_outside``
    outside_batch: int = 0
    w_outside: float = 1.0
    outside_neutral: bool = False  # only other performers' neutral clips (and the walks in place, in every style)
    outside_in_place: bool = True  # with the training split's walks in place (False: other performers' clips alone)
    outside_turns_in_place: bool = True  # False: straight walks and runs alone in place, no turns
    outside_known_content: bool = False  # a window whose content the model has is told it (one-hot), not a random one
    # > 0 (a fine-tune, with init_from): the training windows' transfers are also pulled towards the start model's
    # (learning without forgetting, Li and Hoiem 2016), so that what the run learns elsewhere does not move what the
    # start model did well; that loss weighs ``w_keep``
    w_keep: float = 0.0
    # optimisation
    init_from: str = ""  # fine-tune: a saved generator (stem or shipped name) whose weights start the run
    # > 0: validate and export a moving average of the generator's weights, this decay per step; 0 = the weights
    # themselves
    ema: float = 0.0
    # what --export writes: "best" (validation SRA + CRA), "last" (the final epoch: a fixed budget) or "realistic"
    # (validation realism per style)
    keep: str = "best"
    batch_size: int = 32
    lr_g: float = 1e-4
    lr_d: float = 5e-5
    epochs: int = 60
    max_minutes: float = 0.0  # stop after the epoch that passes this much training time; 0 = none
    val_every: int = 1
    val_windows: int = 2000  # validation windows used per check (fixed subset)
    # classifiers
    classifier_epochs: int = 8
    classifier_stride: int = 8
    classifier_lr: float = 1e-3
    # the online labeller (``styleerd train-labeller``)
    labeller_epochs: int = 6
    labeller_lr: float = 2e-3
    labeller_init_from: str = ""  # fine-tune: a saved labeller (a path without suffix) whose weights start the run
    labeller_outside: bool = False  # other performers' clips join the training clips (``train.batches.outside_clips``)
    labeller_unsure: float = 0.5  # weight of the loss that makes a style the model does not have read as unsure
    # percentiles of the validation streams' distances to the training streams' states from which a reading
    # leans to neutral and at which it is wholly neutral (``train.labeller.fit_familiarity``); () measures none
    labeller_familiar: tuple = (99.0, 99.9)

    @classmethod
    def from_yaml(cls, path: str | Path, **overrides) -> TrainConfig:
        try:
            data = yaml.safe_load(Path(path).read_text()) or {}
        except (OSError, yaml.YAMLError) as e:
            raise StyleERDError(f"cannot read config {path}: {e}") from None
        return cls.from_dict({**data, **overrides}, where=str(path))

    @classmethod
    def from_dict(cls, data: dict, where: str = "config") -> TrainConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise StyleERDError(f"{where}: unknown config keys {unknown}; known: {sorted(known)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}
