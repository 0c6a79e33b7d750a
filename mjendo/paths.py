"""Where mjendo's files are: the checkout's folders, or their copies inside an installed wheel.

The committed data lives at the top of the checkout (``models/``,
``train/policies.yaml``); a wheel carries the same files as
``mjendo/_data/`` (pyproject.toml maps them). Everything that reads or writes them asks
this module, so an installed mjendo finds its scenes, stomach, targets and
shipped policies wherever it is run from. Outputs (runs, evaluations) go
under the checkout when there is one, else under the working directory.
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
_CHECKOUT = PACKAGE.parent
IN_CHECKOUT = (_CHECKOUT / "pyproject.toml").exists() and (_CHECKOUT / "models").is_dir()
DATA = _CHECKOUT if IN_CHECKOUT else PACKAGE / "_data"

MODELS = DATA / "models"
STOMACH_DIR = MODELS / "stomach"
SCENES_DIR = MODELS / "scenes"
ANATOMIES_DIR = MODELS / "anatomies"  # the anatomy benchmark's stomachs and target maps, by seed
TRAINING_CONFIG = DATA / "train" / "policies.yaml"
# Outputs: the checkout (runs/ is ignored by git), or wherever an installed mjendo is run.
WORK = _CHECKOUT if IN_CHECKOUT else Path.cwd()
RUNS = WORK / "runs"
# Built on demand and kept: generated stomachs and the scenes of other stomachs (MJENDO_CACHE moves it).
CACHE = Path(os.environ.get("MJENDO_CACHE", Path.home() / ".cache" / "mjendo"))


def data_path(path: str | Path) -> Path:
    """A path as given, or, when relative and absent from the working directory, one inside mjendo's data (a
    config's ``init_from`` names a folder of the checkout or the installed wheel)."""
    path = Path(path)
    return path if path.is_absolute() or path.exists() else DATA / path


def policies_dir() -> Path:
    """Shipped policies; the environment variable MJENDO_POLICIES points evaluation and viewer elsewhere."""
    return Path(os.environ.get("MJENDO_POLICIES", MODELS / "policies"))
