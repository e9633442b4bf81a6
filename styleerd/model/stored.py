"""Models on disk, read without torch: what inference (transfer, serve, vmc, export) needs.

A model is ``NAME.safetensors`` (weights, with its configuration in the header) + ``NAME.json``
(the same configuration, readable). The shipped models are package data (``styleerd.models``);
a model is named by path, or by name in a folder of ``$STYLEERD_MODELS`` (``os.pathsep``
separated) or among the shipped ones.

The weights come back as float32 numpy arrays under torch's state-dict names, so the torch
modules (``model.checkpoint``, for training and evaluation) and the numpy runtime read the
same files.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numba as nb
import numpy as np
from safetensors import SafetensorError, safe_open

from styleerd.data.features import FeatureStats
from styleerd.errors import StyleERDError
from styleerd.model.config import FAMILIAR, UNFAMILIAR, GeneratorConfig
from styleerd.models import DEFAULT_MODEL, LABELLER, MODELS_DIR
from styleerd.motion.skeleton import Skeleton


def model_folders() -> list[Path]:
    """Where models are looked up by name: ``$STYLEERD_MODELS``'s folders, then the shipped ones."""
    user = [Path(p).expanduser() for p in os.environ.get("STYLEERD_MODELS", "").split(os.pathsep) if p]
    return [*user, MODELS_DIR]


def model_stem(name: str | Path | None, default: str = DEFAULT_MODEL) -> Path:
    """The path (without suffix) of the model ``name``: a path to a model (with or without
    ``.safetensors``), or a bare name found in ``model_folders()``. A name found nowhere comes
    back as given, so that loading it names the missing file."""
    name = Path(name) if name else Path(default)
    stem = name.with_suffix("") if name.suffix in (".safetensors", ".json") else name
    if stem.with_suffix(".safetensors").exists() or len(stem.parts) > 1:
        return stem
    for folder in model_folders():
        if (folder / stem).with_suffix(".safetensors").exists():
            return folder / stem
    return stem


def load_arrays(stem: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """(weights as numpy arrays, configuration) of the model file at ``stem``; anything wrong
    with the file is one ``StyleERDError`` naming it."""
    path = Path(stem).with_suffix(".safetensors")
    try:
        with safe_open(path, framework="numpy") as f:
            text = (f.metadata() or {}).get("styleerd")
            arrays = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118  safe_open is not iterable
    except (OSError, SafetensorError) as e:  # missing, a folder, truncated, not a safetensors file
        raise StyleERDError(f"cannot load model {path}: {getattr(e, 'strerror', None) or e}") from None
    if text is None:
        raise StyleERDError(
            f"cannot load model {path}: no styleerd configuration in its header (not saved by styleerd)"
        )
    try:
        meta = json.loads(text)
    except ValueError as e:
        raise StyleERDError(f"cannot load model {path}: its configuration is not JSON ({e})") from None
    return arrays, meta


def loaded(name: str | Path | None, default: str, build):
    """``(build(arrays, meta), meta)`` of the model ``name``; a configuration and weights that
    do not fit each other is one clear error, not a traceback."""
    path = model_stem(name, default)
    arrays, meta = load_arrays(path)
    try:
        return build(arrays, meta), meta
    except (KeyError, TypeError, ValueError, AttributeError, RuntimeError) as e:
        problem = f"missing {e}" if isinstance(e, KeyError) else str(e).splitlines()[0]
        raise StyleERDError(
            f"cannot load model {path.with_suffix('.safetensors')}: its configuration or weights are incomplete "
            f"({problem})"
        ) from None


@dataclass
class GeneratorWeights:
    """The generator as inference needs it: configuration, skeleton, feature normalisation and
    parameters (float32 arrays under torch's state-dict names). Duck-types the torch
    ``StyleERD`` where the runtime reads it (``config``, ``skeleton``, ``stats()``,
    ``branch_styles``)."""

    config: GeneratorConfig
    skeleton: Skeleton
    feature_stats: FeatureStats
    arrays: dict[str, np.ndarray]
    meta: dict = field(default_factory=dict)
    posture: np.ndarray | None = None  # [styles, J, 3] rotation vectors (``posture_vectors``), None: not measured
    posture_offsets: np.ndarray | None = None  # [styles, J, 3] joint offsets (``posture_offsets``), None: not measured
    posture_frame: str = "heading"  # the frame the offsets are in (``posture_frame``)
    familiar: tuple[float, float] = (FAMILIAR, UNFAMILIAR)  # degrees (``familiar_range``)

    @property
    def branch_styles(self) -> list[int]:
        return self.config.branch_styles

    def stats(self) -> FeatureStats:
        return self.feature_stats


def generator_weights(model) -> GeneratorWeights:
    """``model`` as ``GeneratorWeights``: itself, or the arrays of a torch ``StyleERD``."""
    if isinstance(model, GeneratorWeights):
        return model
    arrays = {k: v.detach().float().cpu().numpy() for k, v in model.state_dict().items()}
    posture = None if model.posture is None else model.posture.double().numpy()
    offsets = None if model.posture_offsets is None else model.posture_offsets.double().numpy()
    return GeneratorWeights(
        model.config,
        model.skeleton,
        model.stats(),
        arrays,
        posture=posture,
        posture_offsets=offsets,
        posture_frame=model.posture_frame,
        familiar=model.familiar,
    )


def posture_vectors(meta: dict, config: GeneratorConfig) -> np.ndarray | None:
    """Each target style's posture (``runtime.posture``), per joint a rotation vector (radians),
    ``[styles, J, 3]`` in the model's style order (a style not measured: no change); None where the
    model file has none."""
    measured = meta.get("posture")
    if measured is None:
        return None
    vectors = np.zeros((len(config.styles), config.n_joints, 3))
    for style, rows in measured["rotation_vectors"].items():
        if style not in config.styles:
            raise ValueError(f"posture of {style!r}, a style the model does not have")
        vectors[config.styles.index(style)] = rows  # numpy refuses a wrong shape
    if not np.isfinite(vectors).all() or np.abs(vectors).max() > np.pi:
        raise ValueError("posture: rotation vectors must be finite and at most pi radians")
    return vectors


def posture_offsets(meta: dict, config: GeneratorConfig) -> np.ndarray | None:
    """Each target style's posture as where it moves each joint (``runtime.posture``), in the frame
    ``posture_frame`` names and the skeleton's units, ``[styles, J, 3]`` in the model's style order; None
    where the model file has none (measured before offsets were)."""
    measured = (meta.get("posture") or {}).get("offsets")
    if measured is None:
        return None
    offsets = np.zeros((len(config.styles), config.n_joints, 3))
    for style, rows in measured.items():
        if style not in config.styles:
            raise ValueError(f"posture offsets of {style!r}, a style the model does not have")
        offsets[config.styles.index(style)] = rows  # numpy refuses a wrong shape
    if not np.isfinite(offsets).all() or np.abs(offsets).max() > 1e6:
        raise ValueError("posture: offsets must be finite and at most 1e6 in the skeleton's units")
    return offsets


POSTURE_FRAMES = ("heading", "body")


def posture_frame(meta: dict) -> str:
    """The frame a model file's posture offsets are in: "heading" (the body's heading, up the
    world's; files measured before the frame was kept) or "body" (the body's own, up from the
    hips to the head: ``motion.kinematics.body_axes``)."""
    frame = (meta.get("posture") or {}).get("frame", "heading")
    if frame not in POSTURE_FRAMES:
        raise ValueError(f"posture frame {frame!r}; valid: {', '.join(POSTURE_FRAMES)}")
    return frame


def familiar_range(meta: dict) -> tuple[float, float]:
    """The identity pass's mean joint angle to the input (degrees) up to which a model's own pose is
    kept, and from which the input's pose plus the posture is (``runtime.stylizer``): as ``styleerd
    familiar`` measured it for the model, else ``model.config``'s FAMILIAR and UNFAMILIAR."""
    familiar = meta.get("familiar")
    if familiar is None:
        return FAMILIAR, UNFAMILIAR
    degrees = familiar.get("degrees") if isinstance(familiar, dict) else familiar
    problem = f"familiar degrees {str(degrees)[:80]}: give two angles, 0 <= the first < the second <= 180"
    if not isinstance(familiar, dict) or not isinstance(degrees, list) or len(degrees) != 2:
        raise ValueError(problem)
    try:
        lo, hi = float(degrees[0]), float(degrees[1])
    except (TypeError, ValueError):
        raise ValueError(problem) from None
    if not 0.0 <= lo < hi <= 180.0:  # NaN fails too
        raise ValueError(problem)
    return lo, hi


def _generator(arrays: dict[str, np.ndarray], meta: dict) -> GeneratorWeights:
    config = GeneratorConfig.from_dict(meta["config"])
    skeleton, stats = Skeleton.from_dict(meta["skeleton"]), FeatureStats.from_dict(meta["stats"])
    weights = {k[len("generator.") :]: v for k, v in arrays.items() if k.startswith("generator.")}
    H, nI, nC, J = config.hidden, len(config.input_styles), len(config.contents), config.n_joints
    expected = {  # the shapes the runtime relies on: a file that disagrees is refused here, not mid-stream
        "encoder.0.weight": (config.encoder[0], config.feature_dim + nI + nC),
        "neutral_h0": (nC, config.neutral_layers, H),
        "branch_h0": (len(config.branch_styles), config.style_layers, H),
        f"decoder.{2 * len(config.decoder)}.weight": (7 * J, config.decoder[-1]),
    }
    if config.added_styles:
        expected["decoder_added"] = (len(config.added_styles), config.decoder[0])
    for key, shape in expected.items():
        if weights[key].shape != shape:
            raise ValueError(f"{key} has shape {weights[key].shape}, the configuration says {shape}")
    if skeleton.n_joints != J:
        raise ValueError(f"the skeleton has {skeleton.n_joints} joints, the configuration says {J}")
    return GeneratorWeights(
        config,
        skeleton,
        stats,
        weights,
        meta,
        posture_vectors(meta, config),
        posture_offsets(meta, config),
        posture_frame(meta),
        familiar_range(meta),
    )


def load_generator_weights(name: str | Path | None = None) -> GeneratorWeights:
    """The generator ``name`` (default: the shipped model) as numpy arrays, without torch."""
    return loaded(name, DEFAULT_MODEL, _generator)[0]


@dataclass
class Familiarity:
    """Where the labeller's state is like those of the streams it learnt from: the Mahalanobis
    distance of the state to the nearest style's mean state at the same time since the stream
    began (its first frames' states are unlike later ones), as a share of the validation streams'
    distances (``train.labeller.fit_familiarity``). A stream ``frames`` frames in takes group
    ``searchsorted(edges, frames, "right")``."""

    edges: np.ndarray  # int64 [G - 1]: the frame counts where the next group starts
    whiten: np.ndarray  # float32 [H, H]: a state's whitened coordinates are ``state @ whiten``
    means: np.ndarray  # float32 [G, styles, H]: each group's style means, whitened
    near: np.ndarray  # float32 [G]: a distance up to this is familiar (1)
    far: np.ndarray  # float32 [G]: one from this on is not (0), linearly between

    NAMES = ("edges", "whiten", "means", "near", "far")

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], hidden: int, n_styles: int) -> Familiarity | None:
        """The ``familiar.*`` arrays of a labeller file, checked against its configuration (``None``
        where the file has none)."""
        if not any(k.startswith("familiar.") for k in arrays):
            return None
        f = cls(*(np.asarray(arrays[f"familiar.{k}"]) for k in cls.NAMES))
        groups = len(f.edges) + 1
        shapes = {"whiten": (hidden, hidden), "means": (groups, n_styles, hidden), "near": (groups,), "far": (groups,)}
        for k, shape in shapes.items():
            if getattr(f, k).shape != shape:
                raise ValueError(f"familiar.{k} has shape {getattr(f, k).shape}, the configuration says {shape}")
        if f.edges.ndim != 1 or f.edges.dtype.kind not in "iu" or np.any(np.diff(f.edges) <= 0) or np.any(f.edges < 1):
            raise ValueError("familiar.edges must be increasing frame counts from 1")
        if not all(np.isfinite(getattr(f, k)).all() for k in shapes) or np.any(f.near >= f.far) or np.any(f.near < 0):
            raise ValueError("familiar: whiten and means must be finite, and 0 <= near < far in every group")
        return cls(
            f.edges.astype(np.int64),
            *(np.ascontiguousarray(getattr(f, k), np.float32) for k in ("whiten", "means", "near", "far")),
        )

    def arrays(self) -> dict[str, np.ndarray]:
        return {f"familiar.{k}": getattr(self, k) for k in self.NAMES}


@dataclass
class LabellerWeights:
    """The online labeller as inference needs it: its configuration (in_dim, n_styles,
    n_contents, hidden), its parameters as float32 arrays, and where its states are familiar
    (``None``: everywhere)."""

    config: dict
    arrays: dict[str, np.ndarray]
    familiar: Familiarity | None = None


def labeller_weights(labeller) -> LabellerWeights:
    """``labeller`` as ``LabellerWeights``: itself, or the arrays of a torch ``OnlineLabeller``."""
    if isinstance(labeller, LabellerWeights):
        return labeller
    return LabellerWeights(
        labeller.config(),
        {k: v.detach().float().cpu().numpy() for k, v in labeller.state_dict().items()},
        labeller.familiar,
    )


def labeller_stem(config: GeneratorConfig) -> Path:
    """The labeller of a model's labels: the first in ``model_folders()`` whose styles are the
    model's input styles and whose contents are its contents (the shipped one otherwise)."""
    for folder in model_folders():
        for sidecar in sorted(folder.glob("*.json")):
            try:
                meta = json.loads(sidecar.read_text())
            except (OSError, ValueError):
                continue
            if (
                isinstance(meta, dict)
                and meta.get("kind") == "styleerd-labeller"
                and meta.get("styles") == list(config.input_styles)
                and meta.get("contents") == list(config.contents)
            ):
                return sidecar.with_suffix("")
    return model_stem(LABELLER, LABELLER)


def load_labeller_weights(name: str | Path | None = None) -> LabellerWeights:
    """The online style/content labeller ``name`` (default: the shipped one), without torch."""

    def build(arrays, meta):
        config = {k: int(meta["config"][k]) for k in ("in_dim", "n_styles", "n_contents", "hidden")}
        weights = {k[len("labeller.") :]: v for k, v in arrays.items() if k.startswith("labeller.")}
        if weights["inp.0.weight"].shape != (config["hidden"], config["in_dim"]):
            raise ValueError(
                f"inp.0.weight has shape {weights['inp.0.weight'].shape}, the configuration says "
                f"{(config['hidden'], config['in_dim'])}"
            )
        return LabellerWeights(config, weights, Familiarity.from_arrays(arrays, config["hidden"], config["n_styles"]))

    return loaded(name, LABELLER, build)[0]


SURE = 0.9  # a style told with at least this probability is kept as it is (``toward_neutral``)
# a style told with less than this is read as absent, its share given to the neutral style: the network
# then runs no branch for it (a posterior has every style above zero, so the input's own-style pass of
# the default pose ran all the branches on every frame)
ABSENT = 0.02


def toward_neutral(
    p_style: np.ndarray, neutral: int, familiar: np.ndarray | None = None, unsure: float = 0.5, sure: float = SURE
) -> np.ndarray:
    """Style posteriors ``[..., nS]`` the labeller is unsure of, leaning to the neutral style:
    a top probability at ``unsure`` or below becomes the neutral label, one at ``sure`` or above
    is kept, linearly between, and what is kept is scaled by ``familiar`` ``[...]``
    (``familiarity``: a state unlike the labeller's training streams' is no reading); then a style
    left under ``ABSENT`` gives its share to the neutral one. Telling the encoder "neutral" when
    in doubt costs little (the target branch still adds the style); a wrong confident style gets
    it subtracted. One compiled pass."""
    p = np.ascontiguousarray(p_style)
    out = np.empty_like(p)
    rows = p.reshape(-1, p.shape[-1])
    trust = np.ones(len(rows)) if familiar is None else np.ascontiguousarray(familiar, np.float64).reshape(-1)
    _toward_neutral(rows, neutral, trust, unsure, sure, ABSENT, out.reshape(-1, p.shape[-1]))
    return out


@nb.njit(cache=True, nogil=True)
def _toward_neutral(p, neutral, familiar, unsure, sure, absent, out):
    for n in range(p.shape[0]):
        keep = min(1.0, max(0.0, (p[n].max() - unsure) / (sure - unsure))) * familiar[n]
        given = 1.0 - keep
        for s in range(p.shape[1]):
            v = keep * p[n, s]
            if s != neutral and v < absent:
                given, v = given + v, 0.0
            out[n, s] = v
        out[n, neutral] += given


def familiarity(
    state: np.ndarray, frames: np.ndarray, f: Familiarity, distance: np.ndarray | None = None
) -> np.ndarray:
    """``[N]`` in [0, 1]: how like the labeller's training streams' the states ``[N, H]`` of
    streams ``frames`` ``[N]`` frames in are (``Familiarity``); each state's distance to the
    nearest mean is also written into ``distance`` where given. One compiled pass."""
    out = np.empty(len(state))
    _familiarity(
        np.ascontiguousarray(state, np.float32),
        np.asarray(frames, np.int64),
        *(f.edges, f.whiten, f.means, f.near, f.far),
        np.empty(len(state)) if distance is None else distance,
        out,
    )
    return out


@nb.njit(cache=True, nogil=True)
def _familiarity(state, frames, edges, whiten, means, near, far, distance, out):
    z = np.dot(state, whiten)
    for n in range(len(state)):
        g = np.searchsorted(edges, frames[n], "right")
        nearest = np.inf
        for s in range(means.shape[1]):
            d = 0.0
            for k in range(z.shape[1]):
                d += (z[n, k] - means[g, s, k]) ** 2
            nearest = min(nearest, d)
        distance[n] = np.sqrt(nearest)
        out[n] = min(1.0, max(0.0, (far[g] - distance[n]) / (far[g] - near[g])))
