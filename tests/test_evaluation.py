"""Evaluation: metrics on constructed trials, and a short real evaluation producing every output."""

import csv
import math

import numpy as np
import pytest

from mjendo import figures
from mjendo.config import ConfigError
from mjendo.evaluation import Trial, evaluate, summarize, wilson


def trial(ok, final, exited=False, peak=1.0):
    return Trial("E", "DE", 0, 0, 5, ok, final, 10, 10.0 if ok else math.nan, exited, 0.5, peak, 3.0)


def test_metrics_on_constructed_trials():
    ts = [trial(True, 1.0), trial(True, 2.0), trial(False, 30.0, exited=True, peak=4.0), trial(False, 10.0)]
    (row,) = summarize(ts)
    assert row["success_rate"] == 50.0
    assert row["ae_success_mm"] == pytest.approx(1.5)  # the paper's AE: successful trials only
    assert row["ae_all_mm"] == pytest.approx(10.75)
    assert row["exits"] == 1 and row["max_peak_force_n"] == 4.0
    assert row["paper_sr"] == 100.0 and row["paper_ae"] == 1.6
    lo, hi = wilson(50, 100)
    assert lo == pytest.approx(0.404, abs=1e-3) and hi == pytest.approx(0.596, abs=1e-3)
    assert wilson(0, 10)[0] == pytest.approx(0.0, abs=1e-12)


def test_short_evaluation_writes_tables_and_figures(tmp_path, monkeypatch):
    monkeypatch.setenv("MJENDO_POLICIES", str(tmp_path / "no_policies_here"))
    res = evaluate(trials=2, controllers=("baseline", "C"), workers=1, out=tmp_path, command="test")
    with open(tmp_path / "trials.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 8
    base = [r for r in rows if r["controller"] == "baseline"]
    assert all(float(r["final_mm"]) >= 0 and int(r["steps"]) <= 80 for r in base)
    # A cell whose policy is missing is marked, the others still ran.
    summary = {(r["controller"], r["env"]): r for r in res["rows"]}
    assert summary[("baseline", "DE")]["error"] == ""
    assert "no policy file" in summary[("C", "DE")]["error"]
    report = (tmp_path / "report.md").read_text()
    assert "| baseline | SE |" in report and "paper SR" in report and "| C | DE | FAILED" in report
    assert (tmp_path / "success_rates.png").stat().st_size > 10_000


def test_trajectory_and_force_figures_from_constructed_paths(tmp_path, stomach):
    rng = np.random.default_rng(0)
    paths = []
    for t in stomach.targets_a[:3]:
        tip = np.cumsum(rng.normal(0, 2, (40, 3)), 0) + stomach.entry * 1e3
        paths.append({"target": t, "tip_mm": tip, "force_n": np.abs(rng.normal(0, 1, 40)),
                      "distance_mm": np.linspace(60, 2, 40), "contact_mm": tip[10], "success": True})
    a = figures.trajectories(paths, tmp_path / "t.png")
    b = figures.force_distance(paths, tmp_path / "f.png")
    assert a.stat().st_size > 10_000 and b.stat().st_size > 10_000


def test_unknown_policy_is_refused():
    with pytest.raises(ConfigError, match="valid: A, B, C, D, E, baseline"):
        evaluate(trials=1, controllers=("Z",))
