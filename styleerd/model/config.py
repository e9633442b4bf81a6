"""The generator's configuration: a plain dataclass, without torch (inference reads it too)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from styleerd.data.features import FeatureLayout

# How unfamiliar an input is (``runtime.stylizer``, pose "input"), from the identity pass's mean joint
# angle to the input (degrees): up to FAMILIAR the network's pose (99 % of Bandai-Namco-2 test
# frames), from UNFAMILIAR on the input's pose plus the style's posture (above every such frame;
# held-out actions of other performers are at 15-50, docs/actions.md). These are a model's range
# until ``styleerd familiar`` measures its own (``model.stored.familiar_range``). It rises by at most RISE
# and falls by at most RELEASE a frame, so nothing pops.
FAMILIAR, UNFAMILIAR, RISE, RELEASE = 10.0, 16.0, 0.25, 0.1
# Rounds of projections that place a two-bone limb's middle joint (``torch_quat.limb_elbow``): the tests
# hold the place to scipy's optimiser's.
LIMB_ROUNDS = 20


@dataclass
class GeneratorConfig:
    n_joints: int
    styles: tuple[str, ...]
    contents: tuple[str, ...]
    neutral_style: str = "normal"
    encoder: tuple[int, ...] = (64, 32)
    hidden: int = 32
    neutral_layers: int = 6
    style_layers: int = 4
    decoder: tuple[int, ...] = (58, 86, 128)
    learned_init: bool = True  # False: the "zero initial states" ablation
    # the decoder's rotations are each joint's change to the input's own rotation (given * change), not the
    # rotation itself: a pose the network never learnt passes through, and the style is what it adds
    pose_change: bool = False
    # styles added after training (``styleerd add-style``), the last of ``styles``: targets
    # only (the encoder and the labeller read input labels over ``input_styles``)
    added_styles: tuple[str, ...] = ()

    def __post_init__(self):
        if self.added_styles and tuple(self.styles[-len(self.added_styles) :]) != tuple(self.added_styles):
            raise ValueError(
                f"added styles {list(self.added_styles)} must be the last of the styles {list(self.styles)}"
            )
        if self.neutral_style not in self.input_styles:
            raise ValueError(
                f"the neutral style {self.neutral_style!r} is not among the input styles {list(self.input_styles)}"
            )

    @property
    def feature_dim(self) -> int:
        return FeatureLayout(self.n_joints).dim

    @property
    def input_styles(self) -> tuple[str, ...]:
        """The styles an input may be labelled with: those the model was trained on."""
        return tuple(self.styles[: len(self.styles) - len(self.added_styles)])

    @property
    def neutral_index(self) -> int:
        return self.styles.index(self.neutral_style)

    @property
    def branch_styles(self) -> list[int]:
        """The styles with a residual branch: every style but the neutral one (added styles last)."""
        return [s for s in range(len(self.styles)) if s != self.neutral_index]

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> GeneratorConfig:
        d = dict(d)
        for key in ("styles", "contents", "encoder", "decoder", "added_styles"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**d)
