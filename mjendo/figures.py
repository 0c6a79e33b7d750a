"""Figures: training curves, tip trajectories, force and distance profiles, success rates with intervals.

Each figure function writes a PNG and returns its path; ``all_figures``
returns (path, caption) pairs that the evaluation report embeds.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from mjendo.config import CONDITIONS, PAPER_EVAL_STEPS
from mjendo.units import to_mm

MIN_RUNS_FOR_SMOOTH_MEAN = 20  # below this a spline through the mean says more than the runs do


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out, dpi: int) -> Path:
    """Write a figure as a 256-colour PNG (a third of the size of matplotlib's RGBA: the figures live in git)."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png")
    _plt().close(fig)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    image = Image.open(buf).convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    image.save(out, format="PNG", optimize=True)
    return out


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
    """Per run, one row of panels: episode reward (moving mean) and success rate vs timesteps."""
    plt = _plt()
    runs = [run] if isinstance(run, Path) else list(run)
    labels = labels or [r.parent.name if r.name.startswith("seed") else r.name for r in runs]
    fig, axes = plt.subplots(len(runs), 2, figsize=(11, 2.6 * len(runs) + 0.6), squeeze=False, sharex="col")
    for (ax1, ax2), r, lab in zip(axes, runs, labels, strict=True):
        ep, ev = _read(Path(r) / "episodes.csv"), _read(Path(r) / "evaluations.csv")
        if ep:
            ax1.plot(ep["timesteps"], _smooth(ep["reward"]), color="C0")
            ax2.plot(ep["timesteps"], _smooth(ep["success"]), color="C0", alpha=0.6, label="training episodes")
        if ev:
            ax2.plot(ev["timesteps"], ev["success_rate"], "o-", color="C3", ms=3, label="evaluation (80 steps)")
        ax1.set(ylabel="episode reward", title=f"{lab}: training reward (moving mean of 50 episodes)")
        ax2.set(ylabel="success rate", ylim=(-0.02, 1.02), title=f"{lab}: success (< 3 mm)")
        for ax in (ax1, ax2):
            ax.grid(alpha=0.3)
        if ax2.get_legend_handles_labels()[0]:
            ax2.legend(fontsize=7, loc="lower right")
    for ax in axes[-1]:
        ax.set_xlabel("timesteps")
    fig.tight_layout()
    return _save(fig, out, 110)


def trajectories(paths: list[dict], out: Path, title: str = "Policy E in DE") -> Path:
    """Tip paths in the dynamic stomach (frontal x-z plane), coloured by target, first contact marked."""
    from mjendo import anatomy

    plt = _plt()
    st = anatomy.load()
    wall = to_mm(st.mesh.points[st.mesh.inner])
    fig, ax = plt.subplots(figsize=(6, 7))
    ax.scatter(wall[:, 0], wall[:, 2], s=4, c="0.8", label="stomach wall (rest)")
    targets = sorted({p["target"] for p in paths})
    cmap = plt.get_cmap("tab20")
    for p in paths:
        c = cmap(targets.index(p["target"]) % 20)
        tip = p["tip_mm"]
        ax.plot(tip[:, 0], tip[:, 2], color=c, lw=1.2, alpha=0.9)
        ax.plot(*p["target_mm"][[0, 2]], "o", color=c, ms=6, mec="k")  # a lumen point, not a vertex, from v1
        if p["contact_mm"] is not None:
            ax.plot(p["contact_mm"][0], p["contact_mm"][2], "x", color="k", ms=7, mew=1.5)
    ax.plot([], [], "x", color="k", label="first wall contact")
    ax.plot([], [], "o", color="0.5", mec="k", label="target (at the trial's start)")
    ax.set(xlabel="x (mm)", ylabel="z (mm)", title=f"{title}: tip trajectories by target ({len(paths)} trials)",
           aspect="equal")
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    return _save(fig, out, 120)


def force_distance(paths: list[dict], out: Path, title: str = "Policy E in DE") -> Path:
    """Normalised contact force and distance along trajectories: every run faint, the mean bold.

    The mean is spline-smoothed only from MIN_RUNS_FOR_SMOOTH_MEAN runs on, and kept
    inside the runs' envelope; with fewer runs the plain mean is drawn.
    """
    from scipy.interpolate import UnivariateSpline

    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    grid = np.linspace(0, 1, 101)
    for ax, key, what, colour in ((axes[0], "force_n", "normalised contact force", "C0"),
                                  (axes[1], "distance_mm", "normalised distance to target", "C3")):
        curves = []
        for p in paths:
            y = np.asarray(p[key], float)
            if len(y) < 2 or y.max() <= 0:
                continue
            y = y / y.max()
            x = np.linspace(0, 1, len(y))
            ax.plot(x, y, color=colour, alpha=0.15, lw=0.8)
            curves.append(np.interp(grid, x, y))
        if curves:
            curves = np.array(curves)
            mean = curves.mean(axis=0)
            if len(curves) >= MIN_RUNS_FOR_SMOOTH_MEAN:
                mean = np.clip(UnivariateSpline(grid, mean, s=len(grid) * 0.002)(grid), curves.min(0), curves.max(0))
                label = f"mean of {len(curves)} runs (spline-smoothed)"
            else:
                label = f"mean of {len(curves)} runs"
            ax.plot(grid, mean, color="k", lw=2.5, label=label)
            ax.legend(fontsize=8)
        ax.set(xlabel="normalised time along the trajectory", ylabel=what, ylim=(-0.02, 1.05),
               title=f"{title}: {what}")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, out, 120)


def success_bars(rows: list[dict], out: Path) -> Path:
    """Success rate per environment and controller with 95 % intervals; the paper's values as hatched outlines."""
    from matplotlib.patches import Patch

    plt = _plt()
    envs = list(CONDITIONS)
    ctrls = list(dict.fromkeys(r["controller"] for r in rows))
    fig, ax = plt.subplots(figsize=(12, 4.2))
    w = 0.8 / max(len(ctrls), 1)
    handles = []
    for i, c in enumerate(ctrls):
        colour = f"C{i}"
        handles.append(Patch(color=colour, label=str(c)))
        for j, e in enumerate(envs):
            r = next((r for r in rows if r["controller"] == c and r["env"] == e), None)
            if r is None or np.isnan(r["success_rate"]):
                continue
            x = j + (i - len(ctrls) / 2 + 0.5) * w
            sr = r["success_rate"]
            err = [[max(sr - r["sr_ci_low"], 0)], [max(r["sr_ci_high"] - sr, 0)]]
            ax.bar(x, sr, w * 0.9, color=colour, yerr=err, ecolor="k", capsize=2, error_kw={"lw": 0.8})
            if not np.isnan(r["paper_sr"]):
                ax.bar(x, r["paper_sr"], w * 0.9, fill=False, hatch="//", edgecolor="k", lw=0.6)
    handles.append(Patch(facecolor="none", edgecolor="k", hatch="//", label="paper"))
    ax.set_xticks(range(len(envs)), envs)
    ax.set(xlabel="environment (FE free, SE static, DE dynamic, UE1/UE2 unseen targets, 2x/3x load)",
           ylabel="success rate % (95 % CI)", ylim=(0, 105),
           title="Success rate per environment (80-step trials, final error < 3 mm)")
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.005, 1.0), title="policy")
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return _save(fig, out, 120)


def study_seeds(summary: list[dict], out: Path) -> Path:
    """One panel per environment: every seed's success rate (dots) and the across-seed mean with its interval."""
    plt = _plt()
    envs = [e for e in CONDITIONS if any(r["env"] == e for r in summary)]
    policies = list(dict.fromkeys(r["policy"] for r in summary))
    fig, axes = plt.subplots(1, len(envs), figsize=(2.6 * len(envs) + 1, 3.6), sharey=True, squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        for i, pol in enumerate(policies):
            r = next((r for r in summary if r["policy"] == pol and r["env"] == env), None)
            if r is None:
                continue
            per_seed = [float(x) for x in str(r["sr_per_seed"]).split()]
            jitter = np.linspace(-0.12, 0.12, len(per_seed)) if len(per_seed) > 1 else [0.0]
            ax.plot(i + np.asarray(jitter), per_seed, "o", color=f"C{i}", alpha=0.7, ms=5)
            ax.errorbar(i + 0.3, r["sr"], yerr=[[r["sr"] - r["sr_low"]], [r["sr_high"] - r["sr"]]], fmt="s",
                        color="k", ms=5, capsize=3)
        ax.set_xticks(range(len(policies)), policies)
        ax.set(title=env, xlabel="policy", xlim=(-0.5, len(policies) - 0.3))
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("success rate %")
    fig.suptitle("Success rate per training seed (dots) and across seeds (black: mean, 95 % CI)", fontsize=10)
    fig.tight_layout()
    return _save(fig, out, 120)


def study_curves(runs: dict[str, list[Path]], out: Path) -> Path:
    """Periodic evaluation (success rate vs timesteps) of every seed, one colour per policy: how far apart
    the policies' learning is, seed by seed (each run's evaluations.csv)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 3.8))
    for i, (policy, folders) in enumerate(runs.items()):
        labelled = False  # one legend entry per policy, on its first seed with evaluations
        for folder in folders:
            ev = _read(Path(folder) / "evaluations.csv")
            if ev:
                smooth = np.convolve(ev["success_rate"], np.ones(3) / 3, mode="valid") if len(ev["timesteps"]) > 3 \
                    else ev["success_rate"]
                ax.plot(ev["timesteps"][len(ev["timesteps"]) - len(smooth):], 100 * smooth, color=f"C{i}",
                        alpha=0.8, lw=1.2, label=None if labelled else policy)
                labelled = True
    ax.set(xlabel="timesteps", ylabel="success rate % (40 trials, mean of 3)", ylim=(-2, 102),
           title="Periodic evaluation during training, every seed")
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[1]:  # a study of runs too short to evaluate has no curves to name
        ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, out, 120)


def success_by_step(trials: list[dict], out: Path, steps: int) -> Path:
    """Share of trials reached by each step, one panel per environment, all targets (solid) and the
    contact-aided ones (dotted): where a curve still climbs at the trial's end, the trial's time limits it."""
    plt = _plt()
    envs = [e for e in CONDITIONS if any(t["env"] == e for t in trials)]
    controllers = list(dict.fromkeys(t["controller"] for t in trials))
    fig, axes = plt.subplots(1, len(envs), figsize=(3.2 * len(envs) + 1.5, 3.4), sharey=True, squeeze=False)
    k = np.arange(steps + 1)
    for ax, env in zip(axes[0], envs, strict=True):
        for i, name in enumerate(controllers):
            cell = [t for t in trials if t["env"] == env and t["controller"] == name]
            for style, chosen in (("-", cell), (":", [t for t in cell if t.get("target_class") == "contact_aided"])):
                if not chosen:
                    continue
                reached = np.array([float(t["steps_to_success"]) for t in chosen if str(t["success"]) == "True"])
                share = 100 * (reached[None, :] <= k[:, None]).sum(1) / len(chosen)
                ax.plot(k, share, style, color=f"C{i}", lw=1.4, label=Path(name).name if style == "-" else None)
        if steps > PAPER_EVAL_STEPS:
            ax.axvline(PAPER_EVAL_STEPS, color="k", lw=0.8, ls="--")
        ax.set(title=env, xlabel="step", xlim=(0, steps), ylim=(-2, 102))
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("trials reached %")
    axes[0][-1].legend(fontsize=7, loc="upper left")
    fig.suptitle("Success by step: all targets (solid), contact-aided ones (dotted)", fontsize=10)
    fig.tight_layout()
    return _save(fig, out, 120)


def all_figures(rows: list[dict], paths: list[dict], out: Path, trials: list[dict] | None = None,
                steps: int = PAPER_EVAL_STEPS) -> list[tuple[Path, str]]:
    """Every figure of the evaluation report into ``out``, each with the caption the report shows."""
    from mjendo.paths import policies_dir

    made = [(success_bars(rows, out / "success_rates.png"),
             "Success rate of each policy in each environment (bars, with 95 % Wilson intervals) next to the "
             "paper's (hatched outlines).")]
    if trials:
        made.append((success_by_step(trials, out / "success_by_step.png", steps),
                     f"Share of trials that reached their target by each step of the {steps}: all targets (solid) "
                     "and contact-aided ones (dotted). A curve still climbing at the end means the trial's "
                     "length, not the policy's aim, limits its success"
                     + (f"; the dashed line marks the paper's {PAPER_EVAL_STEPS}-step trial." if steps >
                        PAPER_EVAL_STEPS else ".")))
    if paths:
        made += [(trajectories(paths, out / "trajectories_E_DE.png"),
                  f"Tip trajectories of policy E in the dynamic stomach (DE), {len(paths)} trials, coloured by "
                  "target; crosses mark the first wall contact."),
                 (force_distance(paths, out / "force_distance_E_DE.png"),
                  "Policy E in DE: contact-force magnitude and distance to the target along each trajectory, "
                  "each normalised by its maximum; faint lines are trials, the bold line their mean.")]
    shipped = {p: policies_dir() / p for p in "ABCDE" if (policies_dir() / p / "episodes.csv").exists()}
    if "A" in shipped:
        made.append((training_curve(shipped["A"], out / "training_A.png", ["A (FE)"]),
                     "Training of shipped policy A in the free environment: episode reward and success rate."))
    rest = [p for p in "BCDE" if p in shipped]
    if rest:
        made.append((training_curve([shipped[p] for p in rest], out / "training_B-E.png", rest),
                     "Training of shipped policies " + ", ".join(rest) + ": one row per policy, episode reward "
                     "and success rate of training episodes and periodic 80-step evaluations."))
    return made


CLASS_COLOURS = {"free": "#4c9be8", "between": "#bbbbbb", "contact_aided": "#e8734c", "out_of_reach": "#555555"}


def target_map(wall: np.ndarray, points: np.ndarray, classes: np.ndarray, lists: dict[str, np.ndarray],
               workspaces: dict[str, np.ndarray], out: Path) -> Path:
    """Two views (x-z: the J's plane; x-y) of the lumen, the free-space workspaces and the classified points.

    ``wall``: lumen vertices at rest; ``points``: candidate positions; ``workspaces``: name -> tip positions
    of the free-space sweep (metres). Lists A and B are ringed.
    """
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.2))
    views = [(0, 2, "x (mm)", "z (mm)")]
    for ax, (name, tips) in zip(axes[:2], workspaces.items(), strict=True):
        for i, j, xl, yl in views:
            ax.scatter(to_mm(wall[:, i]), to_mm(wall[:, j]), s=4, c="#d9a0a0", label="stomach lumen (at rest)")
            ax.scatter(to_mm(tips[::7, i]), to_mm(tips[::7, j]), s=1, c="#2060b0", alpha=0.15,
                       label="tip in free space")
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
        ax.set_title(f"free-space workspace, {name}")
        ax.set_aspect("equal")
        ax.legend(loc="lower left", fontsize=7, markerscale=4)
    ax = axes[2]
    for c, colour in CLASS_COLOURS.items():
        sel = classes == c
        ax.scatter(to_mm(points[sel, 0]), to_mm(points[sel, 2]), s=6, c=colour, label=f"{c} ({sel.sum()})")
    for name, marker in (("A", "o"), ("B", "s")):
        p = points[lists[name]]
        ax.scatter(to_mm(p[:, 0]), to_mm(p[:, 2]), s=40, facecolors="none", edgecolors="k", marker=marker,
                   linewidths=0.8, label=f"list {name} ({len(p)})")
    ax.set_title("candidate targets by class (x-z)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.set_aspect("equal")
    ax.legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    return _save(fig, out, 110)


def anatomies(stomachs: list, out: Path, columns: int = 4) -> Path:
    """Generated stomachs side by side in the J's plane (x-z): the lumen's triangles, cardia, anchors, loads."""
    from matplotlib.collections import PolyCollection

    plt = _plt()
    rows = -(-len(stomachs) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.2 * columns, 3.6 * rows), squeeze=False)
    for ax, st in zip(axes.flat, stomachs, strict=False):
        p = to_mm(st.mesh.points)
        inner = st.mesh.inner
        lumen = [f for f in st.mesh.boundary_faces() if inner[f].all()]
        ax.add_collection(PolyCollection([p[f][:, [0, 2]] for f in lumen], facecolors="#f2c6c6",
                                         edgecolors="#b05050", linewidths=0.3, alpha=0.6))
        ax.scatter(p[st.fixed, 0], p[st.fixed, 2], s=30, c="k", marker="x", label="fixed")
        ax.scatter(p[st.forced, 0], p[st.forced, 2], s=30, c="#2060b0", marker="^", label="forced")
        e = to_mm(st.entry)
        a = st.axis * 40.0
        ax.annotate("", xy=(e[0] + a[0], e[2] + a[2]), xytext=(e[0], e[2]),
                    arrowprops={"arrowstyle": "->", "color": "#208020"})
        i = st.info
        ax.set_title(f"seed {i.get('seed', '-')}: {i['length_mm']:.0f} mm, wall {i['wall_thickness_mm']:.1f} mm",
                     fontsize=9)
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in list(axes.flat)[len(stomachs):]:
        ax.axis("off")
    axes.flat[0].legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    return _save(fig, out, 110)
