"""The shipped models: package data found through ``importlib.resources``, and their licence.
Nothing heavy is imported here, so ``styleerd --help`` can name the styles quickly."""

from __future__ import annotations

import json
import os
from importlib import resources
from pathlib import Path

MODELS_DIR = Path(os.fspath(resources.files(__name__)))
DEFAULT_MODEL = "styleerd-bandai2"
RECOGNISERS = "recognisers-bandai2"
LABELLER = "labeller-bandai2"
FMD = "fmd-bandai2"
LICENCE = "CC BY-NC 4.0 (trained on Bandai-Namco-Research-Motiondataset, CC BY-NC 4.0): non-commercial use"


def shipped_styles() -> tuple[str, ...]:
    """The shipped model's styles, from its readable sidecar."""
    try:
        return tuple(json.loads((MODELS_DIR / f"{DEFAULT_MODEL}.json").read_text())["config"]["styles"])
    except (OSError, ValueError, KeyError):
        return ()
