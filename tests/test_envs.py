"""The navigation MDP through Gymnasium and dm_control: spaces, determinism, rewards, termination."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import mjendo  # noqa: F401  (registers the ids)
from mjendo.baseline import DLSController
from mjendo.config import ConfigError
from mjendo.envs import EndoscopeEnv
from mjendo.rollout import run

IDS = ["mjendo/FE-v0", "mjendo/SE-v0", "mjendo/DE-v0", "mjendo/UE1-v0", "mjendo/UE2-v0", "endogym-v0"]


@pytest.mark.parametrize("env_id", IDS)
def test_check_env(env_id):
    env = gym.make(env_id, force_obs=env_id.endswith("DE-v0"))
    check_env(env.unwrapped, skip_render_check=True)


def seeded_trajectory(seed, steps=20, env_name="DE"):
    env = EndoscopeEnv(env_name)
    rng = np.random.default_rng(123)
    obs, info = env.reset(seed=seed)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(rng.uniform(-0.4, 0.4, 5))
        out.append(obs)
    return info["target_index"], np.array(out)


def test_same_seed_same_trajectory_and_seeds_vary_targets():
    t1, a = seeded_trajectory(7)
    t2, b = seeded_trajectory(7)
    assert t1 == t2
    np.testing.assert_array_equal(a, b)
    env = EndoscopeEnv("SE")
    targets = {env.reset(seed=s)[1]["target_index"] for s in range(8)}
    assert len(targets) >= 3


def test_observations_change_and_do_not_share_memory():
    env = EndoscopeEnv("DE")
    obs0, _ = env.reset(seed=1)
    obs1, _, _, _, info1 = env.step(np.full(5, 0.4))
    obs2, _, _, _, info2 = env.step(np.full(5, 0.4))
    assert not np.allclose(obs1, obs2)
    assert not np.shares_memory(obs1, obs2) and not np.shares_memory(obs0, obs1)
    assert not np.shares_memory(info1["force_N"], info2["force_N"])
    assert obs1.dtype == np.float32 and env.observation_space.contains(obs1)


def test_reward_is_minus_distance_on_ordinary_steps():
    env = EndoscopeEnv("DE")
    env.reset(seed=3)
    for _ in range(5):
        _, r, term, _, info = env.step(np.zeros(5))
        assert not term
        assert r == pytest.approx(-info["distance_mm"])
        # The observation's tip-to-target vector has the reported length.
    obs = env.task.observation()
    assert np.linalg.norm(obs[:3]) == pytest.approx(info["distance_mm"], rel=1e-4)


def test_success_bonus_fires_and_terminates():
    env = EndoscopeEnv("FE")
    env.reset(seed=0)
    # Construct the case: put the (free-floating) target 1 mm ahead of the tip.
    env.task._fe_targets = env.task._fe_targets.copy()
    env.task._fe_targets[env.task.target] = env.task.sim.tip_pos() + 0.001 * env.task.sim.tip_axis()
    _, r, term, trunc, info = env.step(np.zeros(5))
    assert info["is_success"] and term and not trunc
    assert r == pytest.approx(1e4 - info["distance_mm"])


def test_leaving_through_the_cardia_is_penalised_and_terminates():
    env = EndoscopeEnv("SE")
    env.reset(seed=0)
    for _ in range(40):
        _, r, term, trunc, info = env.step(np.array([0, 0, 0, 0, -0.4]))
        if term:
            break
    assert term and info["exited"] and not info["is_success"]
    assert env.task.tip_x_mm() < 15.0
    assert r == pytest.approx(-1e4 - info["distance_mm"])


def test_episode_truncates_at_max_steps():
    env = EndoscopeEnv("SE", max_steps=6)
    env.reset(seed=0)
    flags = [env.step(np.zeros(5))[3] for _ in range(6)]
    assert flags == [False] * 5 + [True]


def test_target_moves_with_the_wall_in_de_not_in_se():
    def travel(name):
        env = EndoscopeEnv(name, randomize_phase=False)
        env.reset(seed=0)
        env.task.insertion = env.task.sim.insertion_range[0]  # keep the scope off the wall
        p = [env.task.target_pos()]
        for _ in range(100):  # 2.5 s: the load reverses at 2 s
            env.step(np.array([0, 0, 0, 0, -0.0]))
            p.append(env.task.target_pos())
        p = np.array(p)
        return np.linalg.norm(p - p[0], axis=1).max() * 1e3

    assert travel("DE") > 0.5
    assert travel("SE") < 0.2


def test_force_blind_observation_has_no_force():
    blind, aware = EndoscopeEnv("SE", force_obs=False), EndoscopeEnv("SE", force_obs=True)
    assert blind.observation_space.shape == (11,) and aware.observation_space.shape == (15,)
    for env in (blind, aware):
        env.reset(seed=0)
        for _ in range(70):  # push straight in until the wall resists
            obs, _, term, _, info = env.step(np.array([0, 0, 0, 0, 0.4]))
            if info["contact"] and np.linalg.norm(info["force_N"]) > 0.05:
                break
        assert info["contact"]
    assert obs[11] == 1.0 and np.linalg.norm(obs[12:]) > 0.05  # aware sees it
    obs_b = blind.task.observation()
    assert obs_b.shape == (11,)
    # The blind observation is exactly the aware one without the force blocks.
    np.testing.assert_allclose(obs_b, blind.task.observation()[:11])


def test_bad_actions_and_names():
    env = EndoscopeEnv("DE")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan, 0, 0, 0, 0]))
    with pytest.raises(ValueError, match="5 values"):
        env.step(np.zeros(3))
    # Out of range is clipped: 10 behaves as 0.4.
    a, b = EndoscopeEnv("SE"), EndoscopeEnv("SE")
    a.reset(seed=0)
    b.reset(seed=0)
    np.testing.assert_array_equal(a.step(np.full(5, 10.0))[0], b.step(np.full(5, 0.4))[0])
    with pytest.raises(ConfigError, match="valid: FE, SE, DE, UE1, UE2"):
        EndoscopeEnv("XX")
    with pytest.raises(ConfigError, match="valid: 'A', 'B'"):
        EndoscopeEnv("DE", target_list="C")
    with pytest.raises(ConfigError, match="camera"):
        EndoscopeEnv("DE", camera="nose")
    with pytest.raises(gym.error.Error):
        gym.make("mjendo/XE-v0")


def test_instability_truncates_with_a_reason():
    env = EndoscopeEnv("DE")
    env.reset(seed=0)
    env.task.sim.data.qvel[:] = 1e7
    _, _, term, trunc, info = env.step(np.zeros(5))
    assert trunc and not term and "instability" in info
    obs, *_ = env.step(np.zeros(5))  # the env recovered: the next step is fine
    assert np.isfinite(obs).all()


def test_baseline_reaches_free_space_targets_in_fe():
    env = EndoscopeEnv("FE", max_steps=80)
    ctrl = DLSController(env.task)
    free = [t for t in env.task.stomach.info["free_reachable_targets"] if t in set(env.task.targets.tolist())]
    reached = [run(env, ctrl, target=t)[0]["is_success"] for t in free[:12]]
    assert sum(reached) >= 3, reached


def test_dm_control_task_matches_the_gym_env():
    from mjendo import suite

    e = suite.load("DE", force_obs=True)
    ts = e.reset()
    assert set(ts.observation) == {"ee_to_target", "ee_velocity", "cable_lengths", "previous_axial_action",
                                   "contact", "force"}
    ts = e.step(np.zeros(5))
    assert ts.reward == pytest.approx(-e.physics.distance_mm())
    assert e.control_timestep() == pytest.approx(0.03)
    blind = suite.load("SE", force_obs=False)
    assert "force" not in blind.reset().observation


def test_render_external_and_tip_cameras():
    env = EndoscopeEnv("DE", render_mode="rgb_array", camera="both", width=160, height=120)
    env.reset(seed=0)
    frame = env.render()
    env.close()
    assert frame.shape == (120, 320, 3)
    assert frame[:, :160].std() > 5 and frame[:, 160:].std() > 1  # neither view is blank


def test_constructing_an_env_prints_nothing(capfd):
    # meshio printed an empty line for every mesh it read while guessing the file format.
    EndoscopeEnv("DE")
    assert capfd.readouterr().out == ""


@pytest.mark.parametrize("name", ["FE", "SE", "DE", "UE1", "UE2"])
def test_dm_control_specs_before_and_after_reset(name):
    # dm_env users ask for specs first; the force blocks read a contact before any reset.
    from mjendo import suite

    env = suite.load(name, force_obs=True)
    before = env.observation_spec()
    assert list(before) == ["ee_to_target", "ee_velocity", "cable_lengths", "previous_axial_action", "contact",
                            "force"]
    assert [s.shape for s in before.values()] == [(3,), (3,), (4,), (1,), (1,), (3,)]
    ts = env.reset()
    assert ts.first() and ts.reward is None and ts.discount is None
    for key, spec in env.observation_spec().items():
        assert spec.shape == before[key].shape and spec.dtype == np.float64
        spec.validate(ts.observation[key])
    ts = env.step(np.zeros(5))
    assert ts.mid() and ts.discount == 1.0 and np.isfinite(ts.reward)
