"""Evaluation: metrics on constructed trials, and a short real evaluation producing every output."""

import math
import shutil

import numpy as np
import pytest

from mjendo import figures, paths
from mjendo.config import ConfigError
from mjendo.evaluation import Trial, evaluate, read_table, summarize, wilson


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
    rows = read_table(tmp_path / "trials.csv.gz")
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
        paths.append({"target": t, "target_mm": tip[-1], "tip_mm": tip, "force_n": np.abs(rng.normal(0, 1, 40)),
                      "distance_mm": np.linspace(60, 2, 40), "contact_mm": tip[10], "success": True})
    a = figures.trajectories(paths, tmp_path / "t.png")
    b = figures.force_distance(paths, tmp_path / "f.png")
    assert a.stat().st_size > 10_000 and b.stat().st_size > 10_000


def test_unknown_policy_is_refused():
    with pytest.raises(ConfigError, match="valid: A, B, C, D, E, baseline"):
        evaluate(trials=1, controllers=("Z",))


def test_an_unknown_env_or_a_stomach_without_its_map_stops_before_any_trial(tmp_path):
    # Each used to run: every trial failed with the same error in the report, or none ran and the tables broke.
    with pytest.raises(ConfigError, match="unknown environment.*XX in --envs; valid: FE, SE"):
        evaluate(trials=1, controllers=("baseline",), envs=("DE", "XX"), out=tmp_path)
    with pytest.raises(ConfigError, match="no trials: FE holds none"):
        evaluate(trials=1, controllers=("baseline",), envs=("FE",), out=tmp_path)
    with pytest.raises(ConfigError, match="holds no stomach.json"):
        evaluate(trials=1, controllers=("baseline",), anatomy=str(tmp_path / "nowhere"), out=tmp_path)
    (tmp_path / "mine").mkdir()  # a stomach whose map was never measured
    shutil.copy(paths.STOMACH_DIR / "stomach.json", tmp_path / "mine")
    with pytest.raises(ConfigError, match="targets.json is missing; measure the map first"):
        evaluate(trials=1, controllers=("baseline",), anatomy=str(tmp_path / "mine"), out=tmp_path)
    assert not (tmp_path / "trials.csv.gz").exists()


def test_default_output_is_untracked_and_a_bigger_study_is_not_overwritten(tmp_path, monkeypatch):
    from mjendo import evaluation

    assert evaluation.default_out("fast").parts[-3:] == ("runs", "eval", "fast")  # runs/ is git-ignored
    (tmp_path / "summary.csv").write_text("controller,env,trials\nE,DE,200\n")
    with pytest.raises(ConfigError, match="made with 200 trials per cell; this run has 10.*--overwrite"):
        evaluate(trials=10, controllers=("baseline",), workers=1, out=tmp_path)
    res = evaluation.main(["--trials", "10", "--policies", "baseline", "--out", str(tmp_path)])
    assert res == 2


def test_report_embeds_every_figure_with_a_caption(tmp_path, monkeypatch):
    monkeypatch.setenv("MJENDO_POLICIES", str(tmp_path / "none"))
    evaluate(trials=1, controllers=("baseline",), workers=1, out=tmp_path, envs=("DE",), fidelity="fast-compliant")
    report = (tmp_path / "report.md").read_text()
    assert "Stomach: the fast stomach with the contact calibrated to the full stomach's tip paths" in report
    embedded = [line for line in report.splitlines() if line.startswith("![")]
    assert embedded and all((tmp_path / line.split("(")[-1].rstrip(")")).exists() for line in embedded)
    assert "success_rates.png" in report and "95 % Wilson intervals" in report


def test_a_run_folder_is_evaluated_like_a_shipped_policy(tmp_path):
    import shutil

    from mjendo.paths import policies_dir

    run = tmp_path / "runs" / "D" / "seed0"
    shutil.copytree(policies_dir() / "v0" / "D", run)  # a task-version-0 policy acts in version 0's task
    res = evaluate(trials=1, controllers=(str(run),), workers=1, out=tmp_path / "out", envs=("DE",))
    (row,) = res["rows"]
    assert row["controller"] == str(run) and row["error"] == "" and row["trials"] == 1
    # the report names the step of the version the policy acted in (version 0's fast stomach: 10 ms), not 20 ms
    assert "physics step 10 ms (task version 0)." in (tmp_path / "out" / "report.md").read_text()
    with pytest.raises(ConfigError, match="holds no model.zip"):
        evaluate(trials=1, controllers=(str(tmp_path),), workers=1, out=tmp_path / "x")


def _figure_of(monkeypatch, draw):
    """Run a figure function and return the matplotlib figure it drew (instead of closing it)."""
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    draw()
    return kept[-1]


def test_success_figure_has_labels_intervals_and_a_distinct_paper_swatch(tmp_path, monkeypatch):
    rows = summarize([trial(True, 1.0), trial(False, 5.0)]) + summarize(
        [Trial("D", "DE", 0, 0, 5, True, 1.0, 10, 10.0, False, 0.1, 0.2, 3.0)])
    fig = _figure_of(monkeypatch, lambda: figures.success_bars(rows, tmp_path / "s.png"))
    ax = fig.axes[0]
    assert ax.get_xlabel() and ax.get_ylabel()
    assert len([c for c in ax.containers if getattr(c, "errorbar", None) is not None]) == 2  # one CI per bar
    legend = ax.get_legend()
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels == ["E", "D", "paper"]
    patches = legend.get_patches()
    assert patches[2].get_hatch() == "//" and patches[2].get_facecolor() != patches[0].get_facecolor()
    # The legend sits outside the axes, never over the bars.
    fig.canvas.draw()
    box, area = legend.get_window_extent(), ax.get_window_extent()
    assert box.x0 >= area.x1 - 1


def test_force_profile_draws_no_spline_through_a_handful_of_runs(tmp_path, monkeypatch):
    paths = [{"force_n": np.array([0.0, 1.0, 0.2, 0.0]), "distance_mm": np.array([30.0, 20.0, 10.0, 2.0])}
             for _ in range(3)]
    fig = _figure_of(monkeypatch, lambda: figures.force_distance(paths, tmp_path / "f.png", "Policy E in DE"))
    for ax in fig.axes:
        assert "Policy E in DE" in ax.get_title()
        mean = [ln for ln in ax.get_lines() if ln.get_linewidth() > 2]
        assert len(mean) == 1 and "spline" not in mean[0].get_label()
        runs = np.array([ln.get_ydata() for ln in ax.get_lines() if ln.get_linewidth() < 2])
        assert mean[0].get_ydata().max() <= runs.max() + 1e-9  # never above every run


def test_training_figure_is_one_row_per_policy(tmp_path, monkeypatch):
    from mjendo.paths import policies_dir

    runs = [policies_dir() / p for p in "BCDE"]
    fig = _figure_of(monkeypatch, lambda: figures.training_curve(runs, tmp_path / "t.png", list("BCDE")))
    assert len(fig.axes) == 8
    for ax in fig.axes:
        assert len(ax.get_lines()) <= 2  # small multiples, not 8 series on one panel


def test_trials_cover_every_target_equally_however_they_are_chunked():
    from mjendo.envs import EndoscopeEnv
    from mjendo.evaluation import trial_targets

    env = EndoscopeEnv("SE")
    listed = env.task.targets.tolist()
    n = 2 * len(listed) + 3
    whole = trial_targets(env, n)
    chunked = [t for j in range(0, n, 7) for t in trial_targets(env, min(7, n - j), j)]
    assert whole == chunked and {k for k, _ in whole} == {None} and {t for _, t in whole} == set(listed)
    counts = [whole.count((None, t)) for t in listed]
    assert max(counts) - min(counts) <= 1


def test_few_trials_per_stomach_still_span_its_whole_list():
    # A list holds its free targets first: over a set of stomachs, 20 trials per stomach once aimed at the
    # first 20 targets of each list only (165 of 200 at free targets where the lists are 2/3 contact-aided).
    from mjendo.evaluation import spread_order

    for n in (1, 3, 31, 65, 85):
        order = spread_order(n)
        assert sorted(order) == list(range(n))  # every target once per len(list) trials
        k = min(n, 8)  # any prefix spreads: each eighth of the list holds about one of the first eight
        assert max(np.bincount(np.array(order[:k]) * k // n, minlength=k)) <= 2
    second_half = [np.mean(np.array(spread_order(n)[:20]) >= n / 2) for n in (31, 40, 65, 85)]
    assert all(0.4 <= f <= 0.6 for f in second_half), second_half


def test_success_by_target_class_counts_each_class_apart():
    from mjendo.evaluation import Trial, by_class

    def trial(target, cls, success, step, final):
        return Trial("E", "DE", 0, 0, target, success, final, 80, step, False, 0.0, 0.0, math.nan,
                     target_class=cls)

    trials = [trial(1, "free", True, 20, 1.0), trial(1, "free", True, 30, 2.0),
              trial(2, "contact_aided", True, 70, 2.5), trial(2, "contact_aided", False, math.nan, 6.0),
              trial(3, "contact_aided", False, math.nan, 9.0), trial(3, "contact_aided", False, math.nan, 4.0),
              *[trial(4, "between", True, 10, 1.0)] * 5]
    (row,) = by_class(trials)
    assert row["free_sr"] == 100.0 and row["free_trials"] == 2 and row["free_success_step"] == 25.0
    assert math.isnan(row["free_miss_mm"])  # no failures
    assert row["contact_aided_sr"] == 25.0 and row["contact_aided_trials"] == 4  # 'between' is neither
    assert row["contact_aided_success_step"] == 70.0 and row["contact_aided_miss_mm"] == 6.0


def test_a_longer_trial_replays_the_paper_trial_and_goes_on(tmp_path):
    # The same seed and controller: the first 80 steps are the 80-step trial's, then the trial continues.
    from mjendo.evaluation import Conditions, run_trials

    seeds = [30_000_000 + i for i in range(2)]
    short, _ = run_trials("baseline", "SE", seeds)
    long, _ = run_trials("baseline", "SE", seeds, conditions=Conditions(steps=95))
    for s, lg in zip(short, long, strict=True):
        assert s.target == lg.target and s.steps <= 80 and lg.steps <= 95
        if s.success:
            assert (lg.success, lg.steps, lg.final_mm) == (s.success, s.steps, s.final_mm)
        else:
            assert s.steps == 80 and (lg.success or lg.steps == 95)
    with pytest.raises(ConfigError, match="--trial-steps must be >= 1"):
        evaluate(trials=1, controllers=("baseline",), out=tmp_path, steps=0)


def test_randomized_trials_draw_the_load_per_trial_and_a_bad_range_stops_before_any(tmp_path):
    # The same trials under half and one and a half times the breathing load: the targets move more
    # under the larger, so the draw reaches the physics of every trial.
    from mjendo.evaluation import Conditions, main, run_trials

    fixed = {"young_scale": [1, 1], "damping_scale": [1, 1], "half_period_s": [2, 2], "friction": [0.1, 0.1],
             "load_tilt_deg": 0.0, "force_noise_n": 0.0, "target_noise_mm": 0.0}
    seeds = [30_000_000 + i for i in range(2)]
    weak, strong = (run_trials("baseline", "DE", seeds, conditions=Conditions(
        randomization={**fixed, "load_scale": [k, k]}))[0] for k in (0.5, 1.5))
    assert not any(t.error for t in weak + strong)
    for w, g in zip(weak, strong, strict=True):
        assert w.target == g.target and g.target_motion_mm > 1.5 * w.target_motion_mm > 0.5
    with pytest.raises(ConfigError, match="young_scale"):
        evaluate(trials=1, controllers=("baseline",), out=tmp_path, randomization={"young_scale": [3, 1]})
    with pytest.raises(SystemExit):
        main(["--randomization", "{friction: 0.2}", "--out", str(tmp_path)])


def test_trials_at_another_physics_step_say_so_and_a_bad_step_stops_before_any(tmp_path):
    # The baseline at the full stomach's 10 ms in the one-cell fast stomach: the trial keeps its 0.1 s control
    # steps, and the report names the step; a step the control period is no multiple of stops the evaluation.
    from mjendo.evaluation import read_table

    evaluate(trials=1, controllers=("baseline",), out=tmp_path, fidelity="fast-coarse", envs=("SE",),
             timestep=0.01)
    (t,) = read_table(tmp_path / "trials.csv.gz")
    assert not t["error"] and float(t["duration_s"]) == pytest.approx(0.1 * int(t["steps"]))
    assert "physics step 10 ms (not the stomach's own)" in (tmp_path / "report.md").read_text()
    with pytest.raises(ConfigError, match="not a multiple of the fast-coarse timestep 0.03"):
        evaluate(trials=1, controllers=("baseline",), out=tmp_path / "bad", fidelity="fast-coarse", timestep=0.03)
    assert not (tmp_path / "bad").exists()


def test_success_by_step_climbs_to_each_cells_success_rate(tmp_path, monkeypatch):
    ts = [{"controller": "E", "env": "DE", "success": ok, "steps_to_success": s, "target_class": c}
          for ok, s, c in ((True, 20.0, "free"), (True, 90.0, "contact_aided"), (False, math.nan, "contact_aided"),
                           (True, 60.0, "contact_aided"))]
    fig = _figure_of(monkeypatch, lambda: figures.success_by_step(ts, tmp_path / "s.png", 120))
    ax = fig.axes[0]
    everything, aided = (ln.get_ydata() for ln in ax.get_lines()[:2])
    assert everything[19] == 0 and everything[20] == 25 and everything[80] == 50 and everything[-1] == 75
    assert aided[80] == pytest.approx(100 / 3) and aided[-1] == pytest.approx(200 / 3)
    assert np.all(np.diff(everything) >= 0)
    assert any(ln.get_xdata()[0] == 80 for ln in ax.get_lines()[2:])  # the paper's trial length is marked
