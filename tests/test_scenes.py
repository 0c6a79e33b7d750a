"""Every scene compiles from its committed file, runs under random controls, and is current."""

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from mjendo import anatomy, scene
from mjendo.config import CONDITIONS, FIDELITIES, ConfigError, Material, fidelity_preset, scene_config
from mjendo.sim import InstabilityError, Simulator

SCENES = [("FE", "fast")] + [(e, f) for e in CONDITIONS if e != "FE" for f in FIDELITIES]


@pytest.mark.parametrize("env,fidelity", SCENES)
def test_scene_runs_one_second_of_random_control(env, fidelity):
    sim = Simulator(env, fidelity)
    rng = np.random.default_rng(0)
    steps = int(round(1.0 / sim.model.opt.timestep))
    for _k in range(0, steps, 10):
        sim.set_controls(rng.uniform(-1, 1, 4) * sim.cable_pull_max, rng.uniform(0.0, 0.08))
        sim.step(10)
    d = sim.data
    assert d.time == pytest.approx(1.0)
    assert all(w.number == 0 for w in d.warning), [w.number for w in d.warning]
    assert np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()
    if sim.has_stomach:
        assert np.isfinite(sim.vertices()).all()


@pytest.mark.parametrize("env,fidelity", [("FE", "fast"), ("SE", "fast"), ("SE", "fast-compliant"), ("DE", "full")])
def test_committed_scene_is_current(env, fidelity):
    # The text alone: the committed scenes' physics is run below (one second of random control each).
    assert scene.scene_path(env, fidelity).read_text() == scene.scene_xml(env, fidelity, check=False)


def test_a_task_version_whose_scene_is_the_current_ones_shares_its_file():
    # Version 2 runs the full stomach as version 1 does (both at 10 ms): one committed file, no copy in v2/.
    assert scene.scene_path("DE", "full", version=2) == scene.scene_path("DE", "full")
    assert scene.scene_path("DE", "fast", version=2) != scene.scene_path("DE", "fast")
    texts = [p.read_bytes() for p in scene.SCENES_DIR.rglob("*.xml")]
    assert len(set(texts)) == len(texts)


def test_one_scene_per_fidelity_plus_fe():
    # SE, DE, UE1 and UE2 share their fidelity's scene; only the load amplitude differs, set by the Simulator.
    assert sorted(p.name for p in scene.SCENES_DIR.glob("*.xml")) == [
        "FE.xml", "stomach_fast-coarse.xml", "stomach_fast-compliant.xml", "stomach_fast.xml", "stomach_full.xml"]
    paths = {scene.scene_path(e, "fast") for e in ("SE", "DE", "UE1", "UE2")}
    assert paths == {scene.SCENES_DIR / "stomach_fast.xml"}
    amplitudes = {e: Simulator(e, "fast").f0 for e in ("SE", "DE", "UE1", "UE2")}
    assert amplitudes == {"SE": 0.0, "DE": 1.0, "UE1": 2.0, "UE2": 3.0}  # paper: 0, f0, 2 f0, 3 f0
    # The fast stomach drives its load with the gains calibrated per load level; full with f0 itself.
    gains = fidelity_preset("fast").load_gains  # the current task version's calibration
    driven = [Simulator(e, "fast").load_amplitude for e in ("DE", "UE1", "UE2")]
    assert driven == pytest.approx([gains[0], 2 * gains[1], 3 * gains[2]])
    assert [Simulator(e, "full").load_amplitude for e in ("DE", "UE1", "UE2")] == [1.0, 2.0, 3.0]
    assert Simulator("FE").f0 == 0.0


def test_dm_control_physics_builds_from_scene():
    # The mujoco/dm-control pin is only right while this works.
    from dm_control import mujoco as dm_mujoco

    physics = dm_mujoco.Physics.from_xml_path(str(scene.scene_path("DE", "fast")))
    physics.step()
    assert physics.data.time > 0


def test_unknown_names_list_valid_ones():
    with pytest.raises(ConfigError, match="valid: FE, SE, DE, UE1, UE2"):
        scene_config("XE")
    with pytest.raises(ConfigError, match="valid: fast, fast-compliant, fast-coarse, full"):
        Simulator("DE", "medium")
    # The compliant fast stomach was calibrated for version 1's scope: version 0 has no scene of it.
    with pytest.raises(ConfigError, match="'fast-compliant' stomach exists from task version 1.*'fast' or 'full'"):
        Simulator("DE", "fast-compliant", version=0)


def test_a_trilinear_grid_without_a_load_calibration_is_refused(monkeypatch):
    # The load gain of a reduced-order stomach belongs to its grid: a grid without one would move the wall
    # by an arbitrary amount, so it gets a clear error naming the calibration, not a silently wrong wall.
    from dataclasses import replace

    from mjendo.config import FIDELITIES

    monkeypatch.setitem(FIDELITIES, "fast-27", replace(FIDELITIES["fast"], name="fast-27", cellcount=(3, 3, 3)))
    with pytest.raises(ConfigError, match=r"grid \(3, 3, 3\) has no load calibration in task version 1.*compare"):
        fidelity_preset("fast-27", 1)
    assert fidelity_preset("fast-coarse").load_gains == pytest.approx((13.76, 14.02, 14.33))
    assert fidelity_preset("fast").load_gains == pytest.approx((2.85, 2.91, 2.98))


def test_version_2_steps_every_stomach_at_the_full_ones_10_ms_and_moves_the_wall_as_version_1():
    # Version 2 is version 1 with the fast stomachs at the FEM one's step (config.VERSIONS): its load gains are
    # rescaled so the breathing load moves the targets as far as version 1's calibrated gains do at 20 ms.
    from mjendo.fidelity import motion_summary

    assert Simulator("DE", "full", version=2).model.opt.timestep == 0.01
    for name in ("fast", "fast-coarse"):
        assert Simulator("DE", name, version=1).model.opt.timestep == 0.02
        assert Simulator("DE", name, version=2).model.opt.timestep == 0.01
        old, new = (motion_summary("DE", fidelity_preset(name, v)) for v in (1, 2))
        assert new["median_mm"] == pytest.approx(old["median_mm"], rel=0.03), (name, old, new)


def test_unusable_physics_parameters_are_rejected_with_the_fix(tmp_path, monkeypatch):
    # With the presets' 1000 iterations the M + hD + h^2 K solve converges even at 1 TPa; an
    # iteration cap too low for a stiff wall is what leaves it under-converged.
    starved = replace(FIDELITIES["full"], iterations=5)
    with pytest.raises(ConfigError, match="too stiff.*lower young or the timestep.*iterations"):
        scene.scene_xml("DE", starved, material=Material(young_pa=1e9))
    with pytest.raises(ConfigError, match="collapses under gravity.*raise young"):
        scene.scene_xml("DE", "fast", material=Material(young_pa=100.0))
    with pytest.raises(ConfigError, match="poisson"):
        scene.build_spec(scene_config("DE", material=Material(poisson=0.5)))
    # One trilinear cell cannot follow training stomach 0's cardia: the retracting scope strikes the wall
    # there (70-80 mm transients), which is not a sag under gravity and gets its own fix, naming the fidelity.
    stomach0 = anatomy.anatomy_dir(0)
    monkeypatch.setattr(scene.paths, "CACHE", tmp_path)  # built here, not found in a cache
    with pytest.raises(ConfigError, match="struck by the scope.*at fast-coarse the wall.*use a finer fidelity"):
        scene.scene_path("SE", "fast-coarse", stomach=stomach0)
    scene.probe(scene.build_spec(scene_config("SE", "fast"), anatomy.load(stomach0), stomach0).compile())
    with pytest.raises(ConfigError, match="unknown solver 'PGS'; valid: CG, Newton"):
        scene.build_spec(scene_config("DE", replace(FIDELITIES["fast"], solver="PGS")))


def test_divergence_raises_our_error():
    sim = Simulator("DE", "fast")
    sim.data.qvel[:] = np.nan
    with pytest.raises(InstabilityError, match="diverged"):
        sim.step(1)
    sim.reset()
    sim.data.qvel[0] = 1e6
    with pytest.raises(InstabilityError, match="lower the timestep"):
        sim.step(1)


def test_scene_files_have_the_paper_contact_settings():
    m = mujoco.MjModel.from_xml_path(str(scene.scene_path("DE", "fast")))
    # Contact distance 0.5 mm; SOFA's 2 mm alarm distance has no MuJoCo counterpart that carries no force
    # (MuJoCo ignores gap for flex contacts: docs/physics.md "Contact").
    assert m.flex_margin[0] == pytest.approx(0.0005) and m.flex_gap[0] == 0.0
    assert m.flex_friction[0, 0] == pytest.approx(0.1)
    # Left lateral decubitus (task version 1): gravity towards the greater curvature, -x; version 0 upright.
    np.testing.assert_allclose(m.opt.gravity, [-9.8, 0, 0])
    v0 = mujoco.MjModel.from_xml_path(str(scene.scene_path("DE", "fast", version=0)))
    np.testing.assert_allclose(v0.opt.gravity, [0, 0, -9.8])


def test_the_jacobian_storage_changes_speed_not_physics():
    # scene.fingerprint leaves the jacobian option out of the hash: dense and sparse must step alike.
    from mjendo.envs import EndoscopeEnv

    assert 'jacobian="dense"' in scene.scene_path("DE", "fast").read_text()
    tips = []
    for jac in (mujoco.mjtJacobian.mjJAC_DENSE, mujoco.mjtJacobian.mjJAC_SPARSE):
        env = EndoscopeEnv("DE")
        env.task.sim.model.opt.jacobian = jac
        env.reset(seed=2)
        start = env.task.sim.tip_pos()
        rng = np.random.default_rng(0)
        for _ in range(60):
            env.step(np.r_[rng.uniform(-0.4, 0.4, 4), 0.3])
        tips.append(env.task.sim.tip_pos())
    assert np.linalg.norm(tips[0] - start) > 0.02  # the scope went 45 mm in: a comparison of moving tips
    assert np.linalg.norm(tips[0] - tips[1]) < 1e-9  # m
