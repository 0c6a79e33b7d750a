"""Per-episode tissue, load, friction and sensor-noise randomization: physics and the task's draw."""

import math

import mujoco
import numpy as np
import pytest

from mjendo import scene
from mjendo.config import CURRENT_VERSION, ConfigError, Material, Randomization, task_config, task_version
from mjendo.envs import EndoscopeEnv
from mjendo.sim import Simulator


def forced_motion(sim: Simulator, stomach, seconds: float) -> np.ndarray:
    """Mean forced-vertex position (m) at every physics step for ``seconds``, the scope withdrawn."""
    sim.set_controls(np.zeros(4), sim.insertion_range[0])
    path = []
    for _ in range(int(round(seconds / sim.model.opt.timestep))):
        sim.step(1)
        path.append(sim.vertices(stomach.forced).mean(0))
    return np.array(path)


def excursion(sim: Simulator, stomach) -> np.ndarray:
    """Peak-to-peak motion (m, per axis) of the forced vertices over the second of two load cycles."""
    path = forced_motion(sim, stomach, 4 * sim.half_period)
    return np.ptp(path[len(path) // 2:], axis=0)


def test_scaling_the_stiffness_at_run_time_is_compiling_the_scaled_modulus():
    sim = Simulator("DE", "fast")
    sim.set_tissue(young_scale=2.0)
    ver = task_version(CURRENT_VERSION)
    xml = scene.scene_xml("DE", "fast", check=False,
                          material=Material(young_pa=2 * Material.young_pa, foundation_per_s2=ver.foundation_per_s2))
    compiled = mujoco.MjModel.from_xml_string(xml)
    np.testing.assert_allclose(sim.model.flex_stiffness, compiled.flex_stiffness, rtol=1e-9)
    sim.restore_scene_values()
    assert not np.allclose(sim.model.flex_stiffness, compiled.flex_stiffness)


def test_a_softer_wall_moves_further_under_the_load(stomach):
    z = []
    for k in (1 / 3, 1.0, 3.0):
        sim = Simulator("DE", "fast")
        sim.set_tissue(young_scale=k)
        z.append(excursion(sim, stomach)[2])
    assert z[0] > z[1] > z[2]
    # The organs around it (the foundation) carry part of the load, so 9x the modulus moves it 3x less or more.
    assert z[0] > 3 * z[2]


def test_a_tilted_load_pushes_along_its_direction_with_its_period(stomach):
    nominal = excursion(Simulator("DE", "fast"), stomach)
    assert nominal[2] > 2 * nominal[0]  # cranio-caudal
    sim = Simulator("DE", "fast")
    sim.set_load(direction=(1.0, 0.0, 0.0), half_period=1.0)
    tilted = excursion(sim, stomach)
    assert tilted[0] > 2 * tilted[2]  # now along x
    # +f0 in [0, T), -f0 in [T, 2T) with T = 1 s: the vertex moves towards +x, then back.
    sim = Simulator("DE", "fast")
    sim.set_load(direction=(1.0, 0.0, 0.0), half_period=1.0)
    x = forced_motion(sim, stomach, 2.0)[:, 0]
    steps = int(round(1.0 / sim.model.opt.timestep))
    assert x[steps - 1] > x[0] + 1e-3 and x[-1] < x[steps - 1] - 1e-3


def test_the_nominal_direction_and_scale_reproduce_the_scene(stomach):
    a = forced_motion(Simulator("DE", "fast"), stomach, 1.0)
    sim = Simulator("DE", "fast")
    sim.set_load(scale=1.0, direction=sim.load_direction)
    np.testing.assert_allclose(forced_motion(sim, stomach, 1.0), a, atol=1e-9)
    sim = Simulator("DE", "fast")
    sim.set_load(scale=0.5)
    half = forced_motion(sim, stomach, 1.0)
    assert np.ptp(half[:, 2]) < 0.7 * np.ptp(a[:, 2])


def test_friction_is_set_on_both_sides_and_restored():
    sim = Simulator("SE", "fast")
    before = sim.model.geom_friction[:, 0].copy()
    sim.set_friction(0.25)
    assert np.all(sim.model.geom_friction[sim.scope_geom, 0] == 0.25)
    assert sim.model.flex_friction[sim.flex, 0] == 0.25
    sim.restore_scene_values()
    np.testing.assert_array_equal(sim.model.geom_friction[:, 0], before)


def test_randomized_episodes_draw_within_the_ranges_and_replay_from_their_seed():
    r = Randomization()
    env = EndoscopeEnv(env="DE", randomization=True, max_steps=5)
    seen = []
    for seed in range(12):
        _, info = env.reset(seed=seed)
        p = info["randomization"]
        for name in Randomization.RANGES:
            if getattr(r, name) is None:  # not drawn by default: the scene's value
                assert p[name] is None
                continue
            lo, hi = getattr(r, name)
            assert lo <= p[name] <= hi
        tilt = math.degrees(math.acos(np.clip(np.dot(p["load_direction"], env.task.sim.load_direction), -1, 1)))
        assert tilt <= r.load_tilt_deg + 1e-6
        assert env.task.sim.half_period == pytest.approx(p["half_period_s"])
        seen.append(p["young_scale"])
    assert max(seen) / min(seen) > 2  # they do vary
    a, info_a = env.reset(seed=7)
    b, info_b = env.reset(seed=7)
    np.testing.assert_array_equal(a, b)
    assert info_a["randomization"] == info_b["randomization"]


def pressed_tip_path(env: EndoscopeEnv, target: int) -> np.ndarray:
    """Tip positions (mm) over 25 steps that insert and bend the scope onto the wall, from load phase 0."""
    env.reset(seed=3)
    env.task.set_target(target)
    path = []
    for k in range(25):
        obs, *_ = env.step(np.array([0.4, -0.4, 0.0, 0.0, 0.4 if k < 18 else 0.0]))
        path.append(env.task.sim.tip_pos() * 1e3)
    return np.array(path)


def test_wall_compliance_spans_the_fast_and_the_compliant_stomachs_contact():
    only = {name: None for name in Randomization.RANGES} | {"load_tilt_deg": 0.0, "force_noise_n": 0.0,
                                                           "target_noise_mm": 0.0, "settle_s": 0.0}
    target = int(EndoscopeEnv(env="DE").task.targets[0])
    paths = {}
    for name, fidelity, compliance in (("fast", "fast", None), ("compliant", "fast-compliant", None),
                                       ("drawn 0", "fast", (0.0, 0.0)), ("drawn 1", "fast", (1.0, 1.0))):
        env = EndoscopeEnv(env="DE", fidelity=fidelity, max_steps=30, randomize_phase=False,
                           randomization=None if compliance is None else only | {"wall_compliance": compliance})
        paths[name] = pressed_tip_path(env, target)
        if compliance is not None:
            env.task.sim.restore_scene_values()
            assert np.array_equal(env.task.sim.model.flex_solimp, EndoscopeEnv(env="DE").task.sim.model.flex_solimp)
    # The scope presses the wall, and the softer contact lets it in further: the two stomachs part.
    assert np.abs(paths["fast"] - paths["compliant"]).max() > 0.5
    np.testing.assert_allclose(paths["drawn 0"], paths["fast"], atol=1e-6)
    np.testing.assert_allclose(paths["drawn 1"], paths["compliant"], atol=1e-6)


def test_sensor_noise_is_in_the_observation_not_in_the_reward():
    env = EndoscopeEnv(env="DE", randomization={"target_noise_mm": 2.0, "force_noise_n": 0.05}, max_steps=20)
    env.reset(seed=1)
    errors, forces = [], []
    for _ in range(10):
        obs, reward, *_rest, info = env.step(np.array([0.0, 0.0, 0.0, 0.0, 0.4]))
        true_delta = (env.task.target_pos() - env.task.sim.tip_pos()) * 1e3
        errors.append(obs[:3] - true_delta)
        forces.append(obs[12:15] - env.task.contact.force)
        assert reward == pytest.approx(-info["distance_mm"])  # the reward sees the true distance
    assert 0.5 < np.std(errors) < 4.0
    assert 0.01 < np.std(forces) < 0.1
    quiet = EndoscopeEnv(env="DE", randomization={"target_noise_mm": 0.0, "force_noise_n": 0.0})
    obs, _ = quiet.reset(seed=1)
    true_delta = (quiet.task.target_pos() - quiet.task.sim.tip_pos()) * 1e3
    np.testing.assert_allclose(obs[:3], true_delta, atol=1e-3)


def test_actuation_noise_scatters_the_executed_steps_about_the_commanded_ones():
    only = {name: None for name in Randomization.RANGES} | {"load_tilt_deg": 0.0, "force_noise_n": 0.0,
                                                           "target_noise_mm": 0.0, "settle_s": 0.0}
    command = np.array([0.3, -0.2, 0.0, 0.1, 0.4])
    executed = {}
    for noise in (0.0, 0.2):
        env = EndoscopeEnv(env="SE", max_steps=40, randomize_phase=False,
                           randomization=only | {"actuation_noise": noise})
        env.reset(seed=3)
        steps, tips = [], []
        for _ in range(30):
            pulls, insertion = env.task.pulls.copy(), env.task.insertion
            obs, *_ = env.step(command)
            assert obs[10] == pytest.approx(command[4])  # the policy observes what it commanded
            steps.append(np.r_[(env.task.pulls - pulls) / env.task.cable_step,
                               (env.task.insertion - insertion) / env.task.insertion_step])
            tips.append(env.task.sim.tip_pos().copy())
        executed[noise] = (np.array(steps), np.array(tips))
    exact, noisy = executed[0.0][0], executed[0.2][0]
    np.testing.assert_allclose(exact, np.broadcast_to(command, exact.shape), atol=1e-12)
    moved = command != 0  # a zero command stays zero: the error is relative to the commanded step
    ratio = noisy[:, moved] / command[moved]
    assert 0.1 < ratio.std() < 0.3 and abs(ratio.mean() - 1.0) < 0.1
    np.testing.assert_array_equal(noisy[:, ~moved], 0.0)
    assert np.linalg.norm(executed[0.2][1][-1] - executed[0.0][1][-1]) > 1e-3  # the tip goes elsewhere


def test_target_give_displaces_the_target_along_the_scopes_push_on_the_wall_nearby():
    only = {name: None for name in Randomization.RANGES} | {"load_tilt_deg": 0.0, "force_noise_n": 0.0,
                                                           "target_noise_mm": 0.0, "settle_s": 0.0}
    push = np.array([0.4, 0.0, 0.0, 0.0, 0.4])  # bend and insert into the wall
    runs = {}
    for give in (None, (1.0, 1.0)):
        env = EndoscopeEnv(env="SE", fidelity="fast-coarse", max_steps=60, randomize_phase=False,
                           randomization=only | {"target_give_mm_per_n": give})
        _, info = env.reset(seed=3, options={"target_index": int(env.task.targets[30])})
        assert info["randomization"]["target_give_mm_per_n"] == (None if give is None else 1.0)
        rows = []
        for _ in range(60):
            _, _, term, trunc, info = env.step(push)
            task = env.task
            wall = task._wall_target()
            c = task.sim.contact(details=True)
            expect = np.zeros(3) if not c.active else -(np.exp(
                -np.sum((c.points - wall) ** 2, axis=1) / (2 * 0.02**2)) @ c.forces) * 1e-3  # 1 mm/N, sigma 20 mm
            rows.append((task.target_pos() - wall, expect, info["distance_mm"],
                         np.linalg.norm(task.sim.tip_pos() - task.target_pos()) * 1e3, c.active))
            if term or trunc:
                break
        runs[give] = rows
    plain, given = runs[None], runs[(1.0, 1.0)]
    assert all(np.all(r[0] == 0) for r in plain)  # without the draw the target is where the wall carries it
    assert sum(r[4] for r in given) >= 10  # the scope pressed the wall on many steps
    for offset, expect, dist, true_dist, _ in given:
        np.testing.assert_allclose(offset, expect, atol=1e-9)
        assert dist == pytest.approx(true_dist)  # the reward's distance is to the displaced target
    peak = max(np.linalg.norm(r[0]) for r in given)
    assert 1e-3 < peak < 5e-3  # a push of about a newton moves the target millimetres, not more
    with pytest.raises(ConfigError, match="target_give_mm_per_n"):
        task_config(randomization=only | {"target_give_mm_per_n": (-0.5, 1.0)})


def test_physics_step_draw_runs_each_episode_at_its_step_and_keeps_the_control_period():
    only = {name: None for name in Randomization.RANGES} | {"load_tilt_deg": 0.0, "force_noise_n": 0.0,
                                                           "target_noise_mm": 0.0, "settle_s": 0.0}
    env = EndoscopeEnv(env="DE", fidelity="fast-coarse", randomization=only | {"physics_step_s": [0.01, 0.02]})
    seen = {}
    for seed in range(8):
        _, info = env.reset(seed=seed)
        dt = info["randomization"]["physics_step_s"]
        assert env.task.sim.model.opt.timestep == dt and env.task.substeps == round(0.1 / dt)
        t0 = env.task.sim.data.time
        env.step(np.array([0.2, 0.0, 0.0, 0.0, 0.4]))
        assert env.task.sim.data.time - t0 == pytest.approx(0.1)  # one control period at either step
        seen[dt] = seen.get(dt, 0) + 1
    assert set(seen) == {0.01, 0.02}
    with pytest.raises(ConfigError, match="not a multiple of the fast timestep 0.03"):
        task_config(randomization=only | {"physics_step_s": [0.01, 0.03]})


@pytest.mark.parametrize("bad, word", [({"young_scale": (2.0, 1.0)}, "young_scale"),
                                       ({"friction": (-0.1, 0.2)}, "friction"),
                                       ({"wall_compliance": (0.5, 1.5)}, "wall_compliance"),
                                       ({"load_tilt_deg": 120.0}, "load_tilt_deg"),
                                       ({"actuation_noise": -0.1}, "actuation_noise"),
                                       ({"physics_step_s": [0.0]}, "physics_step_s"),
                                       ({"physics_step_s": 0.01}, "physics_step_s"),
                                       ({"stiffness": (1, 2)}, "unknown randomization"),
                                       ("yes", "randomization must be")])
def test_bad_randomization_names_the_field(bad, word):
    with pytest.raises(ConfigError, match=word):
        task_config(randomization=bad)


def test_randomization_from_yaml_lists_and_true():
    from mjendo.paths import TRAINING_CONFIG
    from mjendo.train_config import load

    assert task_config(randomization=True).randomization == Randomization()
    cfg = task_config(randomization={"young_scale": [0.5, 2.0]})
    assert cfg.randomization.young_scale == (0.5, 2.0)
    assert task_config(randomization=False).randomization is None
    # A variant that draws the contact alone: its YAML nulls keep every other range at the scene's value.
    r = load("E", TRAINING_CONFIG, variant="paired-impedance").task_config().randomization
    assert r.wall_compliance == (0.0, 1.0)
    assert [n for n in Randomization.RANGES if getattr(r, n) is not None] == ["wall_compliance"]


@pytest.mark.parametrize("dof, tol", [("trilinear", 0.002), ("full", 0.1)])
def test_young_and_poisson_are_the_realised_modulus_and_ratio(dof, tol):
    from mjendo.fidelity import realised_modulus

    e, nu = realised_modulus(dof, poisson=0.3)
    assert e == pytest.approx(1.0, abs=tol)  # not a shear modulus (0.38) nor a doubled convention (2.0)
    assert nu == pytest.approx(0.3, abs=tol / 2 + 0.02 * (dof == "full"))
