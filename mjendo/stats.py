"""Interval estimates across training seeds: a stratified (two-level) bootstrap, as in rliable.

A success rate measured over several training seeds has two sources of
spread: which seeds were trained, and which trials each was evaluated on.
Each bootstrap replicate resamples the seeds with replacement and, within
every drawn seed, its trials with replacement; the statistic is the mean
over the drawn seeds of their per-seed means. The 95 % interval is the
2.5th-97.5th percentile of the replicates (Agarwal et al. 2021, "Deep RL at
the edge of the statistical precipice", whose rliable library stratifies
the same way over runs). Comparisons (E - D) bootstrap each policy
independently and take replicate-wise differences.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

REPS = 4000  # replicates: the percentile interval moves by < 0.3 points between repeats at this size
LEVEL = 0.95


def replicates(per_seed: Sequence[np.ndarray], reps: int = REPS, rng: np.random.Generator | None = None) -> np.ndarray:
    """Bootstrap replicates of the mean over seeds of per-seed trial means (resampling seeds, then trials)."""
    rng = rng or np.random.default_rng(0)
    groups = [np.asarray(g, float) for g in per_seed if len(g)]
    if not groups:
        return np.full(reps, np.nan)
    drawn = rng.integers(0, len(groups), (reps, len(groups)))  # seeds drawn in each replicate
    # Every drawn seed gets its own resample of its trials (a seed drawn twice is resampled twice).
    slot_means = np.empty(drawn.shape)
    for s, g in enumerate(groups):
        slots = drawn == s
        k = int(slots.sum())
        if np.isin(g, (0.0, 1.0)).all():  # 0/1 outcomes: the resampled mean is exactly a binomial draw
            slot_means[slots] = rng.binomial(len(g), g.mean(), k) / len(g)
        else:
            slot_means[slots] = g[rng.integers(0, len(g), (k, len(g)))].mean(axis=1)
    return slot_means.mean(axis=1)


def interval(reps: np.ndarray, level: float = LEVEL) -> tuple[float, float]:
    """Percentile interval of bootstrap replicates."""
    a = (1.0 - level) / 2.0
    lo, hi = np.nanpercentile(reps, [100 * a, 100 * (1 - a)])
    return float(lo), float(hi)


def estimate(per_seed: Sequence[np.ndarray], rng: np.random.Generator, reps: int = REPS) -> dict:
    """Point estimate (mean of per-seed means), 95 % interval and the replicates.

    Estimates that will be compared must draw from one generator (or independent ones): replicates of two
    estimates made from the same random stream are correlated, and their difference's interval too narrow.
    """
    groups = [np.asarray(g, float) for g in per_seed if len(g)]
    r = replicates(groups, reps, rng)
    lo, hi = interval(r)
    point = float(np.mean([g.mean() for g in groups])) if groups else float("nan")
    return {"mean": point, "low": lo, "high": hi, "seeds": len(groups), "replicates": r}


def difference(a: dict, b: dict) -> dict:
    """a - b with a 95 % interval from replicate-wise differences of two independent estimates."""
    d = a["replicates"] - b["replicates"]
    lo, hi = interval(d)
    return {"mean": a["mean"] - b["mean"], "low": lo, "high": hi, "excludes_zero": bool(lo > 0 or hi < 0)}


def crossed(tables: Sequence[np.ndarray], reps: int = REPS, rng: np.random.Generator | None = None,
            groups: Sequence | None = None) -> list[np.ndarray]:
    """Bootstrap replicates resampling training seeds and targets, for several policies at once.

    Each table is (seeds, targets): a policy's success rate per training seed and target (over its trials
    there). Every replicate draws targets with replacement once, shared by all tables (the policies are
    compared on the same targets), and each table's seeds independently; the statistic is the mean over
    drawn seeds and drawn targets. Returns one replicate array per table.

    ``groups`` (one label per target: its stomach) makes the target draw two-stage, as a cluster bootstrap:
    stomachs with replacement, then within each drawn stomach its targets. Targets of one stomach succeed and
    fail together, so the question "on other stomachs" needs the stomachs resampled, not only their points.
    """
    rng = rng or np.random.default_rng(0)
    n_targets = {t.shape[1] for t in tables}
    if len(n_targets) != 1:
        raise ValueError("every table must cover the same targets")
    if groups is not None:
        return _clustered(tables, np.asarray(groups), reps, rng)
    targets = rng.integers(0, n_targets.pop(), (reps, tables[0].shape[1]))
    out = []
    for t in tables:
        seeds = rng.integers(0, t.shape[0], (reps, t.shape[0]))
        by_target = t[:, None, :][seeds[:, :, None], 0, targets[:, None, :]]  # (reps, seeds, targets)
        out.append(by_target.mean(axis=(1, 2)))
    return out


def _clustered(tables: Sequence[np.ndarray], groups: np.ndarray, reps: int, rng: np.random.Generator) -> list:
    """:func:`crossed` with targets drawn stomach by stomach (the drawn stomachs' own target counts)."""
    if len(groups) != tables[0].shape[1]:
        raise ValueError("groups must label every target column")
    members = [np.flatnonzero(groups == g) for g in dict.fromkeys(groups.tolist())]
    seeds = [rng.integers(0, t.shape[0], (reps, t.shape[0])) for t in tables]
    out = [np.empty(reps) for _ in tables]
    for r in range(reps):
        drawn = (members[k] for k in rng.integers(0, len(members), len(members)))
        cols = np.concatenate([m[rng.integers(0, len(m), len(m))] for m in drawn])
        for t, s, o in zip(tables, seeds, out, strict=True):
            o[r] = t[s[r]][:, cols].mean()
    return out
