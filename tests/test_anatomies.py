"""Other stomachs: generated anatomies get their own scenes and run the same task."""

import numpy as np
import pytest

from mjendo import anatomy, paths, targets
from mjendo.config import ANATOMY_SETS, ConfigError, task_config
from mjendo.sim import Simulator
from mjendo.task import NavigationTask


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A cache of its own, so the test builds what a fresh machine builds."""
    monkeypatch.setattr(paths, "CACHE", tmp_path)
    monkeypatch.setattr(paths, "ANATOMIES_DIR", tmp_path / "none")  # ignore committed benchmark stomachs
    return tmp_path


def small_table(st: anatomy.Stomach, n: int = 6) -> targets.TargetTable:
    """A few candidate points deep in the stomach: a map's table without measuring the map."""
    tris, bary = targets.candidates(st)
    depth = np.einsum("nk,nkd->nd", bary, st.mesh.points[tris]) @ st.axis
    rows = np.argsort(-depth)[:n]
    ids = np.arange(n)
    return targets.TargetTable(ids, tris[rows], bary[rows], {"A": ids.tolist()}, {})


def test_a_generated_stomach_gets_its_own_scene_with_the_scope_at_its_cardia(cache):
    folder = anatomy.stomach_dir(5)
    assert folder.is_relative_to(cache) and (folder / "stomach.msh").exists()
    st = anatomy.load(folder)
    sim = Simulator("SE", "fast", stomach=folder)
    assert sim.path.is_relative_to(cache)
    builtin = Simulator("SE", "fast")
    assert sim.model.flex_vertnum[sim.flex] == len(st.mesh.points) != builtin.model.flex_vertnum[builtin.flex]
    # The tip starts start_depth past this stomach's cardia, along its insertion axis.
    along = (sim.tip_pos() - st.entry) @ st.axis
    assert 0.0 < along < 0.05 and np.linalg.norm(sim.tip_pos() - st.entry - along * st.axis) < 0.01
    # The same folder gives the same scene file again (built once).
    assert Simulator("DE", "fast", stomach=folder).path == sim.path


def test_the_load_moves_a_generated_stomachs_fundus_and_the_task_runs_there(cache):
    folder = anatomy.stomach_dir(5)
    st = anatomy.load(folder)
    task = NavigationTask(task_config(env="DE", anatomy=5, max_steps=30), table=small_table(st))
    rng = np.random.default_rng(0)
    task.reset(rng)
    start = task.distance_mm()
    fundus = []
    for _ in range(30):
        res = task.step(np.array([0.0, 0.0, 0.0, 0.0, 0.4]))
        fundus.append(task.sim.vertices(st.forced).mean(0))
    assert "instability" not in res.info
    assert task.distance_mm() < start  # inserting brings the tip towards the deep targets
    # 3 s of the square wave (half period 2 s) switch it at least once: the loaded fundus moves millimetres.
    assert np.ptp(np.array(fundus)[:, 2]) > 1e-3


@pytest.mark.parametrize("bad, word", [(-1, "seed must be >= 0"), (True, "anatomy must be"),
                                       ("/no/such/folder", "holds no stomach.json")])
def test_bad_anatomy_names_the_fix(bad, word):
    with pytest.raises(ConfigError, match=word):
        task_config(anatomy=bad)


def test_a_stomach_without_a_map_says_how_to_measure_it(cache):
    with pytest.raises(ConfigError, match="targets map.*--anatomy"):
        NavigationTask(task_config(env="DE", anatomy=6))


def test_a_users_surface_becomes_an_environment(tmp_path, cache, capsys):
    import trimesh

    # A shape the project did not generate: an ellipsoid lumen in millimetres, as exported from a segmentation.
    s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    s.apply_scale([95.0, 55.0, 50.0])
    surface, folder = tmp_path / "lumen.stl", tmp_path / "my_stomach"
    s.export(surface)
    argv = ["build", "--surface", str(surface), "--entry", "95", "0", "0", "--axis", "-1", "0", "0"]
    with pytest.raises(SystemExit) as exc:  # no --out: the built-in stomach is never overwritten
        anatomy.main(argv)
    assert exc.value.code == 2 and "--surface needs --out FOLDER" in capsys.readouterr().err
    assert anatomy.main([*argv, "--out", str(folder)]) == 0
    assert f"--anatomy {folder}" in capsys.readouterr().out
    st = anatomy.load(folder)
    task = NavigationTask(task_config(env="DE", anatomy=str(folder), max_steps=40), table=small_table(st))
    task.reset(np.random.default_rng(1))
    start = task.distance_mm()
    for _ in range(40):
        res = task.step(np.array([0.0, 0.0, 0.0, 0.0, 0.4]))
    assert "instability" not in res.info and task.distance_mm() < start - 20.0


def write_small_map(st: anatomy.Stomach, folder) -> None:
    """A target map in targets.json's format holding a few deep candidates (lists A, B, F)."""
    import json

    table = small_table(st)
    points = [{"id": int(i), "tri": table.tris[r].tolist(), "bary": table.bary[r].tolist(), "class": "free"}
              for r, i in enumerate(table.ids)]
    ids = table.ids.tolist()
    (folder / "targets.json").write_text(json.dumps({"version": 1, "info": {}, "points": points,
                                                     "lists": {"A": ids[:3], "B": ids[3:], "F": ids}}))


def test_a_set_of_stomachs_is_drawn_per_episode(cache, monkeypatch):
    from mjendo import config
    from mjendo.envs import EndoscopeEnv

    monkeypatch.setitem(config.ANATOMY_SETS, "test", (5, 6))
    for seed in (5, 6):
        write_small_map(anatomy.load(anatomy.stomach_dir(seed)), anatomy.stomach_dir(seed))
    env = EndoscopeEnv("DE", anatomy="test", max_steps=3)
    assert env.anatomies == [5, 6]
    seen, shapes = set(), set()
    for seed in range(8):
        obs, info = env.reset(seed=seed)
        assert env.observation_space.contains(obs)
        seen.add(info["anatomy"])
        shapes.add(int(env.task.sim.model.flex_vertnum[env.task.sim.flex]))
        env.step(env.action_space.sample())
    assert seen == {5, 6} and len(shapes) == 2  # both stomachs, each its own model
    _, info = env.reset(seed=0, options={"anatomy_index": 1})
    assert info["anatomy"] == 6
    with pytest.raises(ConfigError, match="a set of stomachs"):
        NavigationTask(task_config(env="DE", anatomy="test"))


def test_a_list_of_seeds_is_a_set_of_its_own(cache):
    # A held-out set of your own without editing config.ANATOMY_SETS: seeds and ranges, drawn per episode as a set.
    from mjendo.config import anatomy_set
    from mjendo.envs import EndoscopeEnv

    assert anatomy_set("3,5,8-10") == (3, 5, 8, 9, 10) and anatomy_set("test") == ANATOMY_SETS["test"]
    assert anatomy_set("7") is None and anatomy_set(7) is None and anatomy_set("my_stomach") is None
    for bad, word in (("9-8", "runs backwards"), ("5,4-6", "names a stomach twice")):
        with pytest.raises(ConfigError, match=word):
            anatomy_set(bad)
    for seed in (5, 6):
        write_small_map(anatomy.load(anatomy.stomach_dir(seed)), anatomy.stomach_dir(seed))
    env = EndoscopeEnv("DE", anatomy="5-6", max_steps=2)
    assert env.anatomies == [5, 6]
    assert {env.reset(seed=s)[1]["anatomy"] for s in range(8)} == {5, 6}
    with pytest.raises(ConfigError, match="a set of stomachs"):
        NavigationTask(task_config(env="DE", anatomy="5,6"))


def test_the_evaluation_spreads_trials_over_a_set_of_stomachs(cache, monkeypatch):
    from mjendo import config
    from mjendo.envs import EndoscopeEnv
    from mjendo.evaluation import Conditions, per_target, run_trials, trial_targets

    monkeypatch.setitem(config.ANATOMY_SETS, "test", (5, 6))
    for seed in (5, 6):
        write_small_map(anatomy.load(anatomy.stomach_dir(seed)), anatomy.stomach_dir(seed))
    env = EndoscopeEnv("UE2", anatomy="test", max_steps=80)
    pairs = trial_targets(env, 12)
    assert [k for k, _ in pairs] == [0, 1] * 6  # every stomach as often
    assert {t for k, t in pairs if k == 0} == set(env.anatomy_task(0).targets.tolist())  # list B of each: 3
    # in this process: the set above
    trials, _ = run_trials("baseline", "UE2", [11, 12, 13, 14], conditions=Conditions(anatomy="test"))
    assert [t.anatomy for t in trials] == ["5", "6", "5", "6"] and {t.target_class for t in trials} == {"free"}
    assert all(t.error == "" and t.final_mm >= 0 and t.steps >= 1 for t in trials)
    rows = per_target(trials)  # a target id of one stomach is not the same target in another
    assert {(r["anatomy"], r["target"]) for r in rows} == {(t.anatomy, t.target) for t in trials}


def test_the_committed_benchmark_stomachs_are_what_the_generator_builds(tmp_path):
    # Each committed stomach's map indexes its mesh's triangles: a generator that changed would leave
    # maps measured on other stomachs (measure them again: python -m mjendo.targets map --anatomy SEED).
    committed = sorted(paths.ANATOMIES_DIR.glob("seed-*"))
    # The benchmark is whole: every stomach of every set committed with its map.
    for name, seeds in ANATOMY_SETS.items():
        missing = [k for k in seeds if not targets.map_path(paths.ANATOMIES_DIR / f"seed-{k}").exists()]
        assert not missing, f"{name} stomachs {missing} have no map: python -m mjendo.targets map --anatomy {name}"
    for folder in committed:
        built = tmp_path / folder.name
        anatomy.save(anatomy.generate(int(folder.name.removeprefix("seed-"))), built)
        for name in ("stomach.json", "stomach.msh"):
            assert (built / name).read_bytes() == (folder / name).read_bytes(), f"{folder / name} is stale"
        # Its map (gzip-compressed, as benchmark_maps writes it): lists A and B need the wall as the built-in
        # stomach's do.
        path = targets.map_path(folder)
        assert path.name == "targets.json.gz", f"{path}: compress it (targets.write_map to targets.json.gz)"
        free_mm = {p["id"]: p["free_mm"] for p in targets.read_map(path)["points"]}
        table = targets.load(1, path)
        for name in "AB":
            far = np.mean([free_mm[i] >= targets.CONTACT_AIDED_MM for i in table.lists[name]])
            assert len(table.lists[name]) >= 20 and far >= 0.6, (folder, name, len(table.lists[name]), far)
