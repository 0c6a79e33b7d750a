"""The one place where SI units (inside MuJoCo) meet millimetres (task boundary)."""

from __future__ import annotations

import numpy as np

MM_PER_M = 1000.0


def to_mm(x_m):
    """Metres -> millimetres (observations, rewards, reports)."""
    return np.asarray(x_m, dtype=np.float64) * MM_PER_M


def from_mm(x_mm):
    """Millimetres -> metres (parameters given in the paper's units)."""
    return np.asarray(x_mm, dtype=np.float64) / MM_PER_M
