"""The multi-seed study: the bootstrap on known answers, a tiny grid through Ray, resume after a kill, bad addresses."""

import csv
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

from mjendo import stats
from mjendo.config import ConfigError
from mjendo.paths import TRAINING_CONFIG


def test_bootstrap_on_known_answers():
    # One seed that always succeeds and one that never does: resampling the two seeds gives a mean of
    # 0, 0.5 or 1 with probabilities 1/4, 1/2, 1/4, so the 95 % interval is [0, 1] around 0.5.
    rng = np.random.default_rng(0)
    est = stats.estimate([np.ones(500), np.zeros(500)], rng)
    assert est["mean"] == 0.5 and (est["low"], est["high"]) == (0.0, 1.0)
    r = est["replicates"]
    assert np.mean(r == 0.5) == pytest.approx(0.5, abs=0.03) and np.mean(r == 0.0) == pytest.approx(0.25, abs=0.03)
    # Identical seeds at 80 % over 400 trials each: only trial noise is left; 3 seeds x 400 trials behave
    # like 1200 trials, whose binomial 95 % half-width is 1.96 sqrt(0.16 / 1200) = 2.3 points.
    same = [np.r_[np.ones(320), np.zeros(80)]] * 3
    est = stats.estimate(same, rng)
    assert est["mean"] == pytest.approx(0.8)
    half = (est["high"] - est["low"]) / 2
    assert half == pytest.approx(0.0226, abs=0.004)
    # Two estimates of the same data: their difference is centred on 0, does not exclude it, and its interval is
    # sqrt(2) times as wide as each one's (independent replicates; a shared random stream would cancel them).
    d = stats.difference(stats.estimate(same, rng), stats.estimate(same, rng))
    assert d["low"] < 0 < d["high"] and not d["excludes_zero"]
    assert (d["high"] - d["low"]) / 2 == pytest.approx(half * 2 ** 0.5, rel=0.15)
    # A clear difference does exclude 0.
    assert stats.difference(stats.estimate([np.ones(200)] * 3, rng), est)["excludes_zero"]


def test_continuous_metrics_bootstrap_too():
    est = stats.estimate([np.full(50, 2.0), np.full(50, 4.0)], np.random.default_rng(0))
    assert est["mean"] == 3.0 and est["low"] == 2.0 and est["high"] == 4.0


def test_resampling_stomachs_widens_the_interval_when_their_targets_succeed_together():
    # Ten stomachs of ten targets each, two seeds alike: five stomachs where every target succeeds, five where
    # none does. Resampling the 100 targets alone sees 100 independent points (half-width about 10 points);
    # resampling the stomachs sees ten (about 30). Each target its own stomach is the plain target bootstrap.
    table = np.repeat(np.repeat([1.0, 0.0], 50)[None], 2, axis=0)
    stomachs = np.repeat(np.arange(10), 10)
    flat, = stats.crossed([table], rng=np.random.default_rng(0))
    clustered, = stats.crossed([table], rng=np.random.default_rng(0), groups=stomachs)
    single, = stats.crossed([table], rng=np.random.default_rng(0), groups=np.arange(100))
    widths = [np.subtract(*stats.interval(r)[::-1]) for r in (flat, clustered, single)]
    assert np.mean(clustered) == pytest.approx(0.5, abs=0.01)
    assert widths[0] == pytest.approx(0.2, abs=0.03) and widths[1] > 2.5 * widths[0], widths
    assert widths[2] == pytest.approx(widths[0], abs=0.03), widths
    with pytest.raises(ValueError, match="groups must label every target"):
        stats.crossed([table], groups=stomachs[:10])


@pytest.fixture(scope="module")
def tiny_config(tmp_path_factory):
    raw = yaml.safe_load(TRAINING_CONFIG.read_text())
    raw["defaults"].update(checkpoint_every=128, eval_every=512, eval_episodes=1)
    raw["defaults"]["ppo"].update(n_steps=64, batch_size=64, n_epochs=1)
    raw["shipped"] = {}  # the paper's entries: tiny runs from scratch
    path = tmp_path_factory.mktemp("cfg") / "policies.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.integration
@pytest.mark.xdist_group("ray")  # one Ray instance at a time
def test_a_tiny_grid_runs_on_ray_and_reports_intervals(tiny_config, tmp_path, monkeypatch):
    import ray

    from mjendo.study import StudyConfig

    cfg = StudyConfig(policies=("D",), seeds=(1, 2), timesteps=256, trials=3, validation_trials=4,
                      envs=("DE", "UE1"), config=tiny_config, runs=tmp_path / "runs", out=tmp_path / "study")
    try:  # one local cluster for the three studies below: starting Ray and its workers is most of the cost
        _tiny_grid_checks(cfg, tiny_config, tmp_path, monkeypatch)
    finally:
        ray.shutdown()


def _tiny_grid_checks(cfg, tiny_config, tmp_path, monkeypatch):
    import ray

    from mjendo.study import StudyConfig, study

    out = study(cfg, command="test")
    assert ray.is_initialized()  # it went through Ray (a local cluster)
    with open(out / "summary.csv") as f:
        rows = list(csv.DictReader(f))
    assert {(r["policy"], r["env"], r["seeds"], r["trials_per_seed"]) for r in rows} == {
        ("D", "DE", "2", "3"), ("D", "UE1", "2", "3")}
    for r in rows:
        assert float(r["sr_low"]) <= float(r["sr"]) <= float(r["sr_high"])
    for seed in (1, 2):
        assert (out / "seeds" / f"D_seed{seed}" / "study_trials.csv.gz").exists()
        assert (out / "seeds" / f"D_seed{seed}" / "meta.json").exists()
    assert (out / "seeds.png").stat().st_size > 5000 and "seeds.png" in (out / "report.md").read_text()
    assert (out / "curves.png").stat().st_size > 5000 and "curves.png" in (out / "report.md").read_text()
    with open(out / "contact_and_motion.csv") as f:
        contact = {(r["policy"], r["env"]): int(r["trials"]) for r in csv.DictReader(f)}
    assert contact == {("D", "DE"): 6, ("D", "UE1"): 6} and "## Contact and motion" in (out / "report.md").read_text()
    with open(out / "per_target.csv") as f:
        assert sum(int(r["trials"]) for r in csv.DictReader(f)) == 12
    # Each seed is validated on trials of its own, and the best one is named (shipped with --ship-best).
    from mjendo.study import best_seeds

    validation = {s: (out / "seeds" / f"D_seed{s}" / "study_validation.json") for s in (1, 2)}
    assert all(v.exists() for v in validation.values())
    best_seed, best = best_seeds(cfg)["D"]
    assert best_seed in (1, 2) and best["trials"] == cfg.validation_trials == 4 and best["env"] == "DE"
    assert f"| D | {best_seed} |" in (out / "report.md").read_text()
    # Finished trials are skipped when the study runs again: nothing is trained or evaluated again.
    before = (tmp_path / "runs" / "D" / "seed1" / "study_trials.csv.gz").stat().st_mtime_ns
    study(cfg, command="test again")
    assert (tmp_path / "runs" / "D" / "seed1" / "study_trials.csv.gz").stat().st_mtime_ns == before
    # Longer trials keep a cache of their own, and up to step 80 they are the paper-length trials.
    from dataclasses import replace

    from mjendo.evaluation import read_table

    study(replace(cfg, trial_steps=120, out=tmp_path / "study_120"), command="test longer")
    run1 = tmp_path / "runs" / "D" / "seed1"
    assert (run1 / "study_trials.csv.gz").stat().st_mtime_ns == before
    short = {(r["env"], r["trial"]): r for r in read_table(run1 / "study_trials.csv.gz")}
    longer = read_table(run1 / "study_trials_steps120.csv.gz")
    assert len(longer) == len(short) and max(int(r["steps"]) for r in longer) > 80
    for r in longer:
        by_80 = r["success"] == "True" and float(r["steps_to_success"]) <= 80
        assert by_80 == (short[(r["env"], r["trial"])]["success"] == "True") and int(r["steps"]) <= 120
    assert "(120 steps," in (tmp_path / "study_120" / "report.md").read_text()
    # ... unless the scene files or the target lists changed since: then they are evaluated again.
    from mjendo import scene
    from mjendo import study as study_module
    from mjendo.study import _cached_cells

    assert set(_cached_cells(run1, cfg, "D")) == {"DE", "UE1"}
    # A study over one more environment evaluates only that one and keeps the others' trials as they were.
    evaluated = []
    real = study_module.run_trials
    monkeypatch.setattr(study_module, "run_trials",
                        lambda c, env, *a, **k: evaluated.append(env) or real(c, env, *a, **k))
    wider = replace(cfg, envs=("DE", "UE1", "UE2"))
    rows = study_module.trial(wider, "D", 1)
    assert evaluated == ["UE2"] and sorted({r["env"] for r in rows}) == ["DE", "UE1", "UE2"] and len(rows) == 9
    assert {(r["env"], r["trial"], r["success"]) for r in rows if r["env"] != "UE2"} == {
        (r["env"], r["trial"], r["success"]) for r in short.values()}
    monkeypatch.undo()
    before = (run1 / "study_trials.csv.gz").stat().st_mtime_ns
    # A trial that fails inside Ray (here an unreadable checkpoint) stops the study with the task's own
    # error, naming the seed; the finished seed keeps its results.
    ckpts = tmp_path / "runs" / "D" / "seed4" / "checkpoints"
    ckpts.mkdir(parents=True)
    (ckpts / "model_128.zip").write_bytes(b"not a zip")
    (ckpts / "vecnormalize_128.pkl").write_bytes(b"not a pickle")
    broken = StudyConfig(policies=("D",), seeds=(1, 4), timesteps=256, trials=3, validation_trials=4,
                         envs=("DE", "UE1"), config=tiny_config, runs=tmp_path / "runs", out=tmp_path / "study_broken")
    with pytest.raises(ConfigError, match=r"D seed 4 failed: checkpoint .*model_128.zip.* is unreadable"):
        study(broken, command="test broken")
    assert (tmp_path / "runs" / "D" / "seed1" / "study_trials.csv.gz").stat().st_mtime_ns == before
    from mjendo import targets

    monkeypatch.setattr(targets, "fingerprint", lambda version=None: "other lists")  # the lists drawn again
    assert _cached_cells(tmp_path / "runs" / "D" / "seed1", cfg, "D") == {}
    monkeypatch.undo()
    monkeypatch.setattr(scene, "fingerprint", lambda fidelity="fast": "another model")
    assert _cached_cells(tmp_path / "runs" / "D" / "seed1", cfg, "D") == {}


@pytest.mark.integration
@pytest.mark.xdist_group("ray")  # one Ray instance at a time
def test_a_killed_trial_resumes_to_the_same_step_count(tiny_config, tmp_path):
    import json

    def cmd(out):
        return [sys.executable, "-m", "mjendo.train", "--policy", "D", "--seed", "3", "--timesteps", "1024",
                "--config", str(tiny_config), "--out", str(out)]

    proc = subprocess.Popen(cmd(tmp_path / "killed"), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ckpts = tmp_path / "killed" / "D" / "seed3" / "checkpoints"
    deadline = time.time() + 300
    while not list(ckpts.glob("model_*.zip")) and time.time() < deadline and proc.poll() is None:
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)  # no chance to save: resume from the last checkpoint on disk
    proc.wait()
    assert not (tmp_path / "killed" / "D" / "seed3" / "model.zip").exists(), "the run finished before the kill"
    subprocess.run(cmd(tmp_path / "killed"), check=True, capture_output=True)
    # The resumed run ends where an uninterrupted one does: two updates of 8 envs x 64 steps.
    assert json.loads((tmp_path / "killed" / "D" / "seed3" / "meta.json").read_text())["timesteps"] == 1024


@pytest.mark.integration
@pytest.mark.xdist_group("ray")  # one Ray instance at a time
def test_an_unreachable_cluster_address_is_a_clear_error(tmp_path):
    from mjendo.study import StudyConfig, connect

    with pytest.raises(ConfigError, match=r"cannot reach the Ray cluster at 127.0.0.1:9.*ray start --head"):
        connect("127.0.0.1:9")
    with pytest.raises(ConfigError, match="is not host:port"):
        connect("nowhere")
    res = subprocess.run([sys.executable, "-m", "mjendo.study", "--address", "127.0.0.1:9", "--timesteps", "64",
                          "--runs", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "cannot reach the Ray cluster" in res.stderr and "Traceback" not in res.stderr
    with pytest.raises(ConfigError, match="unknown policy"):
        StudyConfig(policies=("Q",)).check()
    with pytest.raises(ConfigError, match="distinct"):
        StudyConfig(seeds=(1, 1)).check()


def test_each_stomach_keeps_its_own_study_cache():
    # A full-stomach study once overwrote the fast study's trial files in the same run folders.
    from mjendo.study import RESULTS_FILE, VALIDATION_FILE, per_stomach

    assert per_stomach(RESULTS_FILE, "fast") == "study_trials.csv.gz"
    names = {per_stomach(f, fid, a) for f in (RESULTS_FILE, VALIDATION_FILE) for fid in ("fast", "full")
             for a in (None, "test")}
    assert len(names) == 8 and "study_trials_full.csv.gz" in names
    assert per_stomach(RESULTS_FILE, "fast", "test") == "study_trials_test.csv.gz"
    assert per_stomach(RESULTS_FILE, "fast", None, 160) == "study_trials_steps160.csv.gz"
    assert per_stomach(RESULTS_FILE, "fast", None, 80) == "study_trials.csv.gz"  # the paper's length


def test_validation_can_pick_the_seed_on_stomachs_of_its_own(tmp_path, monkeypatch):
    # --validation-anatomy val runs a seed's validation trials in those stomachs (E's env, DE) and caches them
    # apart from the training condition's; validating on the very set the study reports is refused.
    from types import SimpleNamespace

    from mjendo import study as study_module
    from mjendo.study import StudyConfig

    run = tmp_path / "E" / "seed4"
    shutil.copytree("models/policies/E", run)
    asked = []

    def fake_trials(run_dir, env, seeds, conditions):
        asked.append((env, conditions.anatomy, len(seeds)))
        return [SimpleNamespace(success=i % 4 != 0, final_mm=2.0) for i in range(len(seeds))], None

    monkeypatch.setattr(study_module, "run_trials", fake_trials)
    held_out = study_module.validate(StudyConfig(policies=("E",), validation_trials=8, anatomy="test",
                                                 validation_anatomy="val"), "E", run)
    own = study_module.validate(StudyConfig(policies=("E",), validation_trials=8), "E", run)
    assert asked == [("DE", "val", 8), ("DE", None, 8)]
    assert held_out["success_rate"] == own["success_rate"] == 0.75
    assert (run / "study_validation_val.json").exists() and (run / "study_validation.json").exists()
    with pytest.raises(ConfigError, match="pick the seed on other stomachs"):
        StudyConfig(policies=("E",), anatomy="test", validation_anatomy="test").check()


def test_a_variant_is_a_study_entry_of_its_own(tmp_path, monkeypatch):
    # E-randomized trains as E's variant, lives beside the paper's policies, and is compared with plain E.
    from mjendo import study

    monkeypatch.setenv("MJENDO_POLICIES", str(tmp_path))
    assert study.split_spec("E") == ("E", None) and study.split_spec("E-scope-curriculum") == ("E", "scope-curriculum")
    assert study.seed_folder("E-randomized", 2) == tmp_path / "variants" / "E-randomized" / "seeds" / "seed2"
    cfg = study.StudyConfig(policies=("E", "E-randomized"), runs=tmp_path / "runs")
    cfg.check()
    assert study.run_folder(cfg, "E-randomized", 1) == tmp_path / "runs" / "E" / "randomized-seed1"
    assert study.train_config(cfg, "E-randomized", 1).task_config().anatomy == "train"
    assert [e for _, e in study._cells(cfg, "E-randomized")] == ["SE", "DE", "UE1", "UE2"]
    with pytest.raises(ConfigError, match="no variant 'nonsense'"):
        study.StudyConfig(policies=("E-nonsense",)).check()

    def row(anatomy, target, success):
        return {"anatomy": anatomy, "target": target, "target_class": "free", "success": str(success)}

    # Target 5 of stomach 100 and target 5 of stomach 101 are different points: never pooled.
    rows = [{**row(a, 5, ok), "controller": c, "env": "DE", "seed_trained": 0, "final_mm": 1.0,
             "mean_force_n": 0.0} for c, a, ok in [("E", 100, True), ("E", 101, False),
                                                     ("E-randomized", 100, True), ("E-randomized", 101, True)]]
    summary, comparisons, per_cell = study.analyse(rows)
    assert [c["comparison"] for c in comparisons] == ["E-randomized - E"]
    # E succeeds in one stomach of two: drawing the stomachs gives 0, 50 or 100 %; E-randomized always 100 %.
    spread = {r["policy"]: (r["sr_low_stomachs"], r["sr_high_stomachs"]) for r in summary}
    assert spread == {"E": (0.0, 100.0), "E-randomized": (100.0, 100.0)}
    by_target = {(t["policy"], t["anatomy"], t["target"]): t["success_pct"] for t in study.per_target_rows(per_cell)}
    assert by_target[("E", "100", 5)] == 100.0 and by_target[("E", "101", 5)] == 0.0
    by_stomach = {(r["policy"], r["anatomy"]): r["success_pct"] for r in study.per_stomach_rows(per_cell)}
    assert by_stomach == {("E", "100"): 100.0, ("E", "101"): 0.0, ("E-randomized", "100"): 100.0,
                          ("E-randomized", "101"): 100.0}
    # D and E trained by the same variant: the paper's E - D asked of that recipe too, and each against its policy.
    rows += [{**row(a, 5, ok), "controller": c, "env": "DE", "seed_trained": 0, "final_mm": 1.0,
              "mean_force_n": 0.0} for c, a, ok in [("D", 100, True), ("D-randomized", 100, False),
                                                      ("D-randomized", 101, False)]]
    _, comparisons, _ = study.analyse(rows)
    found = {c["comparison"]: c["diff_points"] for c in comparisons}
    assert set(found) == {"E - D", "E-randomized - D-randomized", "E-randomized - E", "D-randomized - D"}
    assert found["E-randomized - D-randomized"] == pytest.approx(100.0)
    # A letter the study holds only as the paper trained it is compared with the other's recipe (D-paper - B).
    paper = [{**row(100, 5, ok), "controller": c, "env": "DE", "seed_trained": 0, "final_mm": 1.0,
              "mean_force_n": 0.0} for c, ok in [("B", False), ("D-paper", True), ("E-paper", True)]]
    found = {c["comparison"]: c["diff_points"] for c in study.analyse(paper)[1]}
    assert found == {"E-paper - D-paper": 0.0, "D-paper - B": pytest.approx(100.0)}
    # ... but not when it holds that letter by two recipes too: E-randomized - D would say nothing of either.
    two = paper + [{**r, "controller": c} for r in paper[:1] for c in ("D", "E-randomized")]
    assert "E-randomized - D" not in {c["comparison"] for c in study.analyse(two)[1]}
    # The grid points' rows in another order (Ray's tasks finish in any order): the same estimates and intervals.
    by_point = {}
    for r in rows:
        by_point.setdefault((r["controller"], r["seed_trained"]), []).append(r)
    assert study.analyse([r for k in reversed(list(by_point)) for r in by_point[k]])[:2] == study.analyse(rows)[:2]


def test_comparisons_resample_seeds_and_targets():
    from mjendo import study

    rng = np.random.default_rng(0)

    def rows(p_success):  # 3 seeds x 10 targets x 2 trials
        return {s: [{"success": str(bool(rng.random() < p_success(k))), "target": k} for k in range(10)
                    for _ in range(2)] for s in range(3)}

    always, never = rows(lambda k: 1.0), rows(lambda k: 0.0)
    assert study.over_targets(always, never, rng) == (100.0, 100.0)
    # A seed evaluated now (int targets) beside seeds read from their cache (CSV strings) is the same study.
    cached = {s: [{**t, "target": str(t["target"])} for t in ts] for s, ts in always.items() if s}
    assert study.over_targets({0: always[0], **cached}, never, rng) == (100.0, 100.0)
    # Success that depends on the target only: the seeds agree, the targets carry all the spread.
    half = rows(lambda k: float(k < 5))
    lo, hi = study.over_targets(half, never, rng)
    assert 15 < lo < 50 < hi < 85


def test_seeds_that_are_not_numbers_are_a_usage_error(capsys):
    from mjendo.study import main

    with pytest.raises(SystemExit) as exit_:
        main(["--seeds", "a,b"])
    assert exit_.value.code == 2 and "expected comma-separated whole numbers, got 'a,b'" in capsys.readouterr().err


def test_each_policy_can_hold_its_own_seeds(capsys):
    # A study of D's two finished seeds beside E's three must not train D seed 2 to fill a rectangle.
    from mjendo.config import ConfigError
    from mjendo.study import StudyConfig, main

    cfg = StudyConfig(policies=("D", "E"), seeds=(0, 1, 2), seeds_for=(("D", (0, 1)),))
    cfg.check()
    assert cfg.grid() == [("D", 0), ("D", 1), ("E", 0), ("E", 1), ("E", 2)]
    with pytest.raises(ConfigError, match="names policy 'C', which is not in --policies D,E"):
        StudyConfig(seeds_for=(("C", (0,)),)).check()
    with pytest.raises(ConfigError, match="distinct"):
        StudyConfig(seeds_for=(("D", (3, 3)),)).check()
    with pytest.raises(SystemExit) as exit_:
        main(["--seeds-for", "D:0,1"])
    assert exit_.value.code == 2 and "expected POLICY=SEEDS such as D=0,1" in capsys.readouterr().err


def test_a_study_without_ray_says_how_to_install_it(monkeypatch, capsys, tmp_path):
    from mjendo.study import main

    monkeypatch.setitem(sys.modules, "ray", None)  # what `import ray` meets where Ray is not installed
    assert main(["--policies", "E", "--seeds", "0", "--runs", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "error: the study runs on Ray: install it with `pip install 'mjendo[study]'`" in err
    assert not any(tmp_path.iterdir())  # nothing trained, nothing written


def test_contact_and_motion_pools_seeds_and_splits_by_class(monkeypatch):
    from mjendo import evaluation, study

    monkeypatch.setattr(evaluation, "target_classes", lambda: {1: "free", 2: "contact_aided"})

    def row(target, success, motion, contact, peak):
        return {"target": target, "success": str(success), "target_motion_mm": motion, "duration_s": 2.0,
                "contact_share": contact, "over_1n_share": 0.1 * (peak > 1), "over_2n_share": 0.0, "peak_force_n": peak}

    per_cell = {("E", "DE"): {0: [row(1, True, 1.0, 0.0, 0.0), row(2, False, 5.0, 0.5, 1.5)],
                              1: [row(1, True, 2.0, 0.0, 0.0), row(2, True, 6.0, 1.0, 3.0)]}}
    (r,) = study.contact_and_motion(per_cell)
    assert (r["trials"], r["free_sr"], r["contact_aided_sr"]) == (4, 100.0, 50.0)
    assert r["median_target_motion_mm"] == 3.5 and r["contact_share_pct"] == 37.5
    assert r["over_1n_pct"] == pytest.approx(5.0) and r["median_peak_force_n"] == 0.75
    targets = {(t["target"], t["class"]): (t["trials"], t["success_pct"]) for t in study.per_target_rows(per_cell)}
    assert targets == {(1, "free"): (2, 100.0), (2, "contact_aided"): (2, 50.0)}


def test_a_published_seed_is_adopted_with_its_study_trials(tmp_path, monkeypatch):
    # A fresh clone holds each study seed's policy and trials under models/policies/<P>/seeds/seed<N>/:
    # the study adopts them as the run instead of training again (A seed 0 stands in for any seed).
    from mjendo import artifacts, paths
    from mjendo.study import RESULTS_FILE, StudyConfig, adopt_shipped, run_folder, seed_folder

    policies = tmp_path / "policies"
    monkeypatch.setenv("MJENDO_POLICIES", str(policies))
    published = seed_folder("A", 0)
    shutil.copytree(paths.MODELS / "policies" / "A", published)
    (published / RESULTS_FILE).write_text("controller,env\n")
    cfg = StudyConfig(policies=("A",), seeds=(0,), runs=tmp_path / "runs")
    run = run_folder(cfg, "A", 0)
    (run / "tb").mkdir(parents=True)  # a folder without a checkpoint or a model (a start that failed)
    (run / "episodes.csv").write_text("timesteps,reward,length,success,final_mm\n")
    assert adopt_shipped(cfg, "A", 0)
    assert (run / artifacts.MODEL_FILE).exists() and (run / RESULTS_FILE).exists() and (run / "ADOPTED").exists()
    assert not adopt_shipped(cfg, "A", 0)  # the run exists now: never overwritten
    # Another seed's files are not this seed's run.
    assert not adopt_shipped(StudyConfig(policies=("A",), seeds=(1,), runs=tmp_path / "runs"), "A", 1)


def test_a_published_fine_tune_is_adopted_only_from_where_its_variant_starts(tmp_path, monkeypatch):
    # A fine-tuned variant's published seed is its run when it started from the variant's init_from;
    # one that started elsewhere (or a from-scratch policy with a fine-tune's meta) is not.
    from mjendo import artifacts, paths
    from mjendo.study import StudyConfig, adopt_shipped, seed_folder, train_config

    monkeypatch.setenv("MJENDO_POLICIES", str(tmp_path / "policies"))
    cfg = StudyConfig(policies=("E-short-horizon",), seeds=(0,), runs=tmp_path / "runs")
    published = seed_folder("E-short-horizon", 0)
    shutil.copytree(paths.MODELS / "policies" / "variants" / "E-short-horizon" / "seeds" / "seed0", published)
    meta = artifacts.read_meta(published)
    assert meta["init_from"] == train_config(cfg, "E-short-horizon", 0).init_from
    artifacts.write_meta(published, {**meta, "init_from": "models/policies/E"})
    assert not adopt_shipped(cfg, "E-short-horizon", 0)
    artifacts.write_meta(published, meta)
    assert adopt_shipped(cfg, "E-short-horizon", 0)
    a = StudyConfig(policies=("A",), seeds=(0,), runs=tmp_path / "runs")
    shutil.copytree(paths.MODELS / "policies" / "A", seed_folder("A", 0))
    artifacts.write_meta(seed_folder("A", 0), {**artifacts.read_meta(seed_folder("A", 0)), "init_from": "x"})
    assert not adopt_shipped(a, "A", 0)


def test_the_shipped_seed_is_in_git_once(tmp_path, monkeypatch):
    # The shipped seed's published folder holds no model.zip or vecnormalize.pkl (they are the shipped
    # policy's): loading it, and adopting it as the study's run, take them from models/policies/<P>/.
    from mjendo import artifacts, paths
    from mjendo.study import StudyConfig, adopt_shipped, run_folder, seed_folder

    policies = tmp_path / "policies"
    monkeypatch.setenv("MJENDO_POLICIES", str(policies))
    shutil.copytree(paths.MODELS / "policies" / "A", policies / "A", ignore=shutil.ignore_patterns("seeds"))
    published = seed_folder("A", 0)
    published.mkdir(parents=True)
    shutil.copy2(policies / "A" / artifacts.META_FILE, published / artifacts.META_FILE)
    assert artifacts.model_home(published) == policies / "A"
    assert artifacts.load(published).meta["seed"] == 0
    cfg = StudyConfig(policies=("A",), seeds=(0,), runs=tmp_path / "runs")
    assert adopt_shipped(cfg, "A", 0)
    run = run_folder(cfg, "A", 0)
    for name in (artifacts.MODEL_FILE, artifacts.NORM_FILE):
        assert (run / name).read_bytes() == (policies / "A" / name).read_bytes()
    # A seed folder whose meta names another run is not the shipped policy's: its missing model stays missing.
    meta = artifacts.read_meta(published)
    artifacts.write_meta(published, {**meta, "wall_s": meta["wall_s"] + 1.0})
    assert artifacts.model_home(published) == published
    with pytest.raises(artifacts.PolicyError, match="published seed kept without its weights.*--seed 0"):
        artifacts.load(published)


def test_a_report_points_at_a_published_seed_instead_of_copying_it(tmp_path, monkeypatch):
    # A seed's trials live in git once: the report's record of a published seed is its published folder;
    # a seed that is not published (or published with other trials) is copied under <out>/seeds/.
    from mjendo.study import StudyConfig, results_file, run_folder, seed_folder, seed_record

    monkeypatch.setenv("MJENDO_POLICIES", str(tmp_path / "policies"))
    cfg = StudyConfig(policies=("D",), seeds=(1,), runs=tmp_path / "runs", out=tmp_path / "out")
    run, published = run_folder(cfg, "D", 1), seed_folder("D", 1)
    for folder in (run, published):
        folder.mkdir(parents=True)
        (folder / results_file(cfg)).write_bytes(b"trials")
        (folder / "evaluations.csv").write_text("timesteps,success_rate\n")
    copy = tmp_path / "out" / "seeds" / "D_seed1"
    copy.mkdir(parents=True)  # an earlier report's copy
    assert seed_record(cfg, "D", 1) == published and not copy.exists()
    (run / results_file(cfg)).write_bytes(b"other trials")
    assert seed_record(cfg, "D", 1) == copy and (copy / results_file(cfg)).read_bytes() == b"other trials"


def test_a_variant_seed_published_without_weights_is_reported_from_its_trials(tmp_path, monkeypatch):
    # A variant's non-shipped seed that no variant starts from is published with its trials, validation and
    # meta only: the study reports it without training or evaluating, and loading it says how to get it back.
    from mjendo import artifacts, paths
    from mjendo.study import StudyConfig, adopt_shipped, run_folder, seed_folder, started_from, trial, will_train

    cfg = StudyConfig(policies=("E-randomized",), seeds=(1,), anatomy="test", envs=("DE", "UE2"), trials=200,
                      runs=tmp_path / "runs")
    published = paths.MODELS / "policies" / "variants" / "E-randomized" / "seeds" / "seed1"
    assert not (published / artifacts.MODEL_FILE).exists() and published.resolve() not in started_from(cfg)
    assert (paths.MODELS / "policies" / "variants" / "E-curriculum-randomized" / "seeds" / "seed0").resolve() \
        in started_from(cfg)  # randomized-free-pool starts there: those weights stay
    monkeypatch.setenv("MJENDO_POLICIES", str(tmp_path / "policies"))
    shutil.copytree(published, seed_folder("E-randomized", 1))
    assert adopt_shipped(cfg, "E-randomized", 1) and not will_train(cfg, "E-randomized", 1)
    # Asked for stomachs its trials do not cover, it has no weights to evaluate: the study says it trains again.
    assert will_train(StudyConfig(policies=("E-randomized",), seeds=(1,), anatomy="val", envs=("DE",), trials=200,
                                  runs=tmp_path / "runs"), "E-randomized", 1)
    rows = trial(cfg, "E-randomized", 1)
    run = run_folder(cfg, "E-randomized", 1)
    assert len(rows) == 400 and not (run / artifacts.MODEL_FILE).exists()  # nothing trained or evaluated
    with pytest.raises(artifacts.PolicyError, match="without its weights.*--variant randomized --seed 1"):
        artifacts.load(seed_folder("E-randomized", 1))
