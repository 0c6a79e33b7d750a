"""Figures: training curves, tip trajectories, force and distance profiles, success-rate bars."""

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
    for r, lab in zip(runs, labels, strict=True):
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


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def trajectories(paths: list[dict], out: Path) -> Path:
    """Tip paths in the dynamic stomach (frontal x-z plane), coloured by target, first contact marked."""
    from mjendo import anatomy

    plt = _plt()
    st = anatomy.load()
    wall = st.mesh.points[st.mesh.inner] * 1e3
    fig, ax = plt.subplots(figsize=(6, 7))
    ax.scatter(wall[:, 0], wall[:, 2], s=4, c="0.8", label="stomach wall (rest)")
    targets = sorted({p["target"] for p in paths})
    cmap = plt.get_cmap("tab20")
    for p in paths:
        c = cmap(targets.index(p["target"]) % 20)
        tip = p["tip_mm"]
        ax.plot(tip[:, 0], tip[:, 2], color=c, lw=1.2, alpha=0.9)
        ax.plot(*st.mesh.points[p["target"]][[0, 2]] * 1e3, "o", color=c, ms=6, mec="k")
        if p["contact_mm"] is not None:
            ax.plot(p["contact_mm"][0], p["contact_mm"][2], "x", color="k", ms=7, mew=1.5)
    ax.plot([], [], "x", color="k", label="first wall contact")
    ax.plot([], [], "o", color="0.5", mec="k", label="target")
    ax.set(xlabel="x (mm)", ylabel="z (mm)", title="Policy E in DE: tip trajectories by target", aspect="equal")
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def force_distance(paths: list[dict], out: Path) -> Path:
    """Normalised contact-force magnitude and distance along trajectories: faint runs, bold smoothed mean."""
    from scipy.interpolate import UnivariateSpline

    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    grid = np.linspace(0, 1, 101)
    for ax, key, title in ((axes[0], "force_n", "normalised contact force"),
                           (axes[1], "distance_mm", "normalised distance to target")):
        curves = []
        for p in paths:
            y = np.asarray(p[key], float)
            if len(y) < 2 or y.max() <= 0:
                continue
            y = y / y.max()
            x = np.linspace(0, 1, len(y))
            ax.plot(x, y, color="C0" if key == "force_n" else "C3", alpha=0.15, lw=0.8)
            curves.append(np.interp(grid, x, y))
        if curves:
            mean = np.mean(curves, axis=0)
            smooth = UnivariateSpline(grid, mean, s=len(grid) * 0.002)(grid)
            ax.plot(grid, np.clip(smooth, 0, 1), color="k", lw=2.5, label=f"mean of {len(curves)} runs")
            ax.legend(fontsize=8)
        ax.set(xlabel="normalised time along the trajectory", ylabel=title, ylim=(-0.02, 1.05), title=title)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def success_bars(rows: list[dict], out: Path) -> Path:
    """Success rate per environment and controller, ours (solid) next to the paper's (hatched)."""
    plt = _plt()
    envs = ["FE", "SE", "DE", "UE1", "UE2"]
    ctrls = list(dict.fromkeys(r["controller"] for r in rows))
    fig, ax = plt.subplots(figsize=(12, 4))
    w = 0.8 / max(len(ctrls), 1)
    for i, c in enumerate(ctrls):
        for j, e in enumerate(envs):
            r = next((r for r in rows if r["controller"] == c and r["env"] == e), None)
            if r is None:
                continue
            x = j + (i - len(ctrls) / 2 + 0.5) * w
            ax.bar(x, 0 if np.isnan(r["success_rate"]) else r["success_rate"], w * 0.9, color=f"C{i}",
                   label=c if j == 1 or (e == "FE" and c == "A") else None)
            if not np.isnan(r["paper_sr"]):
                ax.bar(x, r["paper_sr"], w * 0.9, fill=False, hatch="//", edgecolor="0.3", lw=0.5)
    ax.bar([], [], fill=False, hatch="//", edgecolor="0.3", label="paper")
    ax.set_xticks(range(len(envs)), envs)
    ax.set(ylabel="success rate %", ylim=(0, 105), title="Success rate per environment (80-step trials)")
    handles, labels = ax.get_legend_handles_labels()
    uniq = dict(zip(labels, handles, strict=True))
    ax.legend(uniq.values(), uniq.keys(), fontsize=8, ncol=4)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def all_figures(rows: list[dict], paths: list[dict], out: Path) -> list[Path]:
    """Every figure of the evaluation report into ``out``."""
    from mjendo.policies import POLICIES_DIR

    made = [success_bars(rows, out / "success_rates.png")]
    if paths:
        made += [trajectories(paths, out / "trajectories_E_DE.png"),
                 force_distance(paths, out / "force_distance_E_DE.png")]
    shipped = {p: POLICIES_DIR / p for p in "ABCDE" if (POLICIES_DIR / p / "episodes.csv").exists()}
    if "A" in shipped:
        made.append(training_curve(shipped["A"], out / "training_A.png", ["A (FE)"]))
    rest = [p for p in "BCDE" if p in shipped]
    if rest:
        made.append(training_curve([shipped[p] for p in rest], out / "training_B-E.png", rest))
    return made
