"""``python -m mjendo.compare``: two policies over their training seeds, from evaluation reports.

The study trains and evaluates a grid itself. In the full FEM stomach, seeds are evaluated a few at a time
(``python -m mjendo.evaluation --policies runs/E/...-seed0-...,... --fidelity full``, one draw per command);
this reads those reports' ``trials.csv.gz``, takes every controller whose name contains ``--a`` (or ``--b``)
as one training seed of that policy, pools each seed's trials over the reports, and gives the study's
estimates: success with a 95 % interval over seeds and trials, and a - b over seeds and trials and over seeds
and targets (:mod:`mjendo.stats`).

    python -m mjendo.compare --a runs/E/paper-step-seed --b runs/D/paper-step-seed --env DE \\
        eval/full/variants/paper-step eval/full/variants/D-paper-step ...
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from mjendo import cli, stats
from mjendo.config import CONDITIONS, ConfigError
from mjendo.evaluation import read_table
from mjendo.study import over_targets, success_of

TRIALS_FILE = "trials.csv.gz"


def trials_files(paths: list[Path]) -> list[Path]:
    """Each path as a trials table: a report folder's ``trials.csv.gz`` or the file itself."""
    files = [p / TRIALS_FILE if p.is_dir() else p for p in paths]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise ConfigError(f"no trials table at {', '.join(missing)}: name evaluation report folders (their "
                          f"{TRIALS_FILE}) or the tables themselves")
    return files


def seeds_of(rows: list[dict], pattern: str, env: str) -> dict[str, list[dict]]:
    """Controller name -> its trials in ``env``, for every controller whose name contains ``pattern``, in name
    order: the bootstrap then gives the same intervals whatever order the reports were named in."""
    out: dict[str, list[dict]] = {}
    for r in rows:
        if pattern in r["controller"] and r["env"] == env and not r.get("error"):
            out.setdefault(r["controller"], []).append(r)
    if not out:
        names = sorted({r["controller"] for r in rows})
        raise ConfigError(f"no controller in {env} contains {pattern!r}; the tables hold {', '.join(names)}")
    return dict(sorted(out.items()))


def compare(paths: list[Path], a: str, b: str, env: str = "DE") -> dict:
    """Estimates of ``a`` and ``b`` (each a dict of stats.estimate plus its per-seed rates) and ``a - b``."""
    rows = [r for f in trials_files(paths) for r in read_table(f)]
    by = {name: seeds_of(rows, pattern, env) for name, pattern in (("a", a), ("b", b))}
    shared = sorted(set(by["a"]) & set(by["b"]))
    if shared:
        raise ConfigError(f"{', '.join(shared)} match both --a {a!r} and --b {b!r}: make the patterns disjoint")
    rng = np.random.default_rng(0)  # one stream, as the study's analysis draws its estimates
    out = {}
    for name, seeds in by.items():
        per_seed = [np.array([success_of(t) for t in ts], float) for ts in seeds.values()]
        out[name] = {**stats.estimate(per_seed, rng), "controllers": list(seeds),
                     "per_seed": [float(s.mean()) for s in per_seed], "trials": [len(s) for s in per_seed]}
    diff = stats.difference(out["a"], out["b"])
    lo, hi = over_targets(*(dict(enumerate(by[k].values())) for k in ("a", "b")), rng)
    out["a - b"] = {**diff, "low_targets": lo / 100, "high_targets": hi / 100}
    return out


def report(result: dict, a: str, b: str, env: str) -> str:
    """The comparison as a short markdown table (success in %)."""
    lines = [f"| policy | seeds | trials per seed | {env} success % (95 % over seeds and trials) | per seed |",
             "|---|---|---|---|---|"]
    for name, pattern in (("a", a), ("b", b)):
        e = result[name]
        n = f"{min(e['trials'])}" + (f"-{max(e['trials'])}" if min(e["trials"]) != max(e["trials"]) else "")
        lines.append(f"| `{pattern}` | {e['seeds']} | {n} | "
                     f"{100 * e['mean']:.1f} ({100 * e['low']:.1f} to {100 * e['high']:.1f}) | "
                     + " ".join(f"{100 * s:.1f}" for s in e["per_seed"]) + " |")
    d = result["a - b"]
    lines.append(f"\na - b: {100 * d['mean']:+.1f} points; 95 % interval {100 * d['low']:+.1f} to "
                 f"{100 * d['high']:+.1f} over seeds and trials, {100 * d['low_targets']:+.1f} to "
                 f"{100 * d['high_targets']:+.1f} over seeds and targets")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.compare", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("reports", nargs="+", type=Path, help="evaluation report folders or their trials.csv.gz")
    ap.add_argument("--a", required=True, help="text in the controller names of policy a's seeds")
    ap.add_argument("--b", required=True, help="text in the controller names of policy b's seeds")
    ap.add_argument("--env", default="DE", choices=list(CONDITIONS))
    args = ap.parse_args(argv)
    return cli.run(lambda: print(report(compare(args.reports, args.a, args.b, args.env), args.a, args.b, args.env)),
                   ConfigError)


if __name__ == "__main__":
    sys.exit(main())
