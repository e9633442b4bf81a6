"""The generator's configuration: a plain dataclass, without torch (inference reads it too)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from styleerd.data.features import FeatureLayout


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

    @property
    def feature_dim(self) -> int:
        return FeatureLayout(self.n_joints).dim

    @property
    def neutral_index(self) -> int:
        return self.styles.index(self.neutral_style)

    @property
    def branch_styles(self) -> list[int]:
        """The styles with a residual branch: every style but the neutral one."""
        return [s for s in range(len(self.styles)) if s != self.neutral_index]

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "GeneratorConfig":
        d = dict(d)
        for key in ("styles", "contents", "encoder", "decoder"):
            d[key] = tuple(d[key])
        return cls(**d)
