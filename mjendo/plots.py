"""Figures: training curves (episode reward and success rate vs timesteps)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


def _read(path: Path) -> dict[str, np.ndarray]:
    if not path.exists():
        return {}
    with open(path) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return {}
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def _smooth(y: np.ndarray, n: int = 50) -> np.ndarray:
    if len(y) < 2:
        return y
    n = max(1, min(n, len(y) // 5 or 1))
    c = np.cumsum(np.insert(y, 0, 0.0))
    out = (c[n:] - c[:-n]) / n
    return np.concatenate([np.full(n - 1, np.nan), out])


def training_curve(run: Path | list[Path], out: Path, labels: list[str] | None = None) -> Path:
    """Episode reward (smoothed) and success rate vs timesteps for one or more runs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [run] if isinstance(run, Path) else list(run)
    labels = labels or [r.parent.name if r.name.startswith("seed") else r.name for r in runs]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for r, lab in zip(runs, labels):
        ep, ev = _read(Path(r) / "episodes.csv"), _read(Path(r) / "evaluations.csv")
        if ep:
            line, = ax1.plot(ep["timesteps"], _smooth(ep["reward"]), label=lab)
            ax2.plot(ep["timesteps"], _smooth(ep["success"]), color=line.get_color(), alpha=0.5,
                     label=f"{lab} (training episodes)")
            if ev:
                ax2.plot(ev["timesteps"], ev["success_rate"], "o-", color=line.get_color(), ms=3,
                         label=f"{lab} (evaluation, 80 steps)")
    ax1.set(xlabel="timesteps", ylabel="episode reward (moving mean)", title="training reward")
    ax2.set(xlabel="timesteps", ylabel="success rate", ylim=(-0.02, 1.02), title="success (< 3 mm)")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return Path(out)
