"""The MDP written once (mjendo/mdp.py): NumPy and torch give the same rewards, flags and observations, and
the CPU task's step is exactly that function of its state."""

import numpy as np
import pytest
import torch

from mjendo import mdp
from mjendo.config import ConfigError, task_config
from mjendo.task import NavigationTask, obs_bounds


def states(n=64, seed=0):
    rng = np.random.default_rng(seed)
    tip = rng.normal(0, 0.05, (n, 3))
    target = tip + rng.normal(0, 0.004, (n, 3))  # some within 3 mm, most not
    origin, axis = np.array([0.0, 0.0, 0.02]), np.array([0.0, 0.0, -1.0])
    force = rng.normal(0, 0.5, (n, 3))
    steps = rng.integers(1, 140, n)
    ok = rng.random(n) > 0.1
    return tip, target, origin, axis, force, steps, ok


def test_numpy_and_torch_agree_on_every_output():
    cfg = task_config(env="DE", force_penalty=0.5)
    args = states()
    a = mdp.outcome(cfg, *args)
    b = mdp.outcome(cfg, *(torch.as_tensor(x) for x in args))
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_allclose(np.asarray(a[k], float), b[k].numpy().astype(float), rtol=1e-12, atol=1e-12,
                                   err_msg=k)
    lo, hi = obs_bounds(cfg)
    parts = (a["delta"], np.random.default_rng(1).normal(0, 0.1, (64, 3)), np.full((64, 4), 0.09),
             np.linspace(-0.4, 0.4, 64), (a["force_n"] > 0.5) * 1.0, args[4])
    o1 = mdp.observe(np, cfg, *parts, lo, hi)
    o2 = mdp.observe(torch, cfg, *(torch.as_tensor(x) for x in parts), torch.as_tensor(lo), torch.as_tensor(hi))
    np.testing.assert_array_equal(o1, o2.numpy())
    scoped = task_config(env="DE", scope_obs=True)
    lo, hi = obs_bounds(scoped)
    scope = (np.linspace(0.0, 0.16, 64), args[0], args[0] / np.linalg.norm(args[0], axis=1, keepdims=True))
    s1 = mdp.observe(np, scoped, *parts, lo, hi, scope)
    s2 = mdp.observe(torch, scoped, *(torch.as_tensor(x) for x in parts), torch.as_tensor(lo), torch.as_tensor(hi),
                     tuple(torch.as_tensor(x) for x in scope))
    np.testing.assert_array_equal(s1, s2.numpy())
    np.testing.assert_array_equal(s1[:, :15], o1)  # the scope's state is appended, the rest unchanged
    timed = task_config(env="DE", scope_obs=True, time_obs=True)
    lo, hi = obs_bounds(timed)
    left = np.linspace(0.0, 1.0, 64)
    t1 = mdp.observe(np, timed, *parts, lo, hi, scope, left)
    t2 = mdp.observe(torch, timed, *(torch.as_tensor(x) for x in parts), torch.as_tensor(lo), torch.as_tensor(hi),
                     tuple(torch.as_tensor(x) for x in scope), torch.as_tensor(left))
    np.testing.assert_array_equal(t1, t2.numpy())
    np.testing.assert_array_equal(t1[:, :22], s1)
    np.testing.assert_allclose(t1[:, 22], left)  # the time left comes last of all


def test_the_paper_rewards_and_an_unstable_step():
    cfg = task_config(env="DE")
    tip, origin, axis = np.zeros((3, 3)), np.array([0.0, 0.0, 0.02]), np.array([0.0, 0.0, -1.0])
    target = tip + np.array([[0.001, 0, 0], [0.01, 0, 0], [0.01, 0, 0]])  # 1 mm, 10 mm, 10 mm
    ok = np.array([True, True, False])
    out = mdp.outcome(cfg, tip, target, origin, axis, np.zeros((3, 3)), np.array([5, 5, 5]), ok)
    assert out["reward"][0] == pytest.approx(1e4 - 1.0) and out["terminated"][0]
    assert out["reward"][1] == pytest.approx(-10.0) and not out["terminated"][1] and not out["truncated"][1]
    # Diverged physics: no success, no exit, reward 0, truncated.
    assert out["reward"][2] == 0.0 and out["truncated"][2] and not out["terminated"][2]
    # Behind the cardia (x_EE < 15 mm in the paper's frame): -1e4 and terminated.
    far = mdp.outcome(cfg, np.array([[0, 0, 0.01]]), np.array([[0, 0, -0.05]]), origin, axis, np.zeros((1, 3)),
                      np.array([1]), np.array([True]))
    assert far["exited"][0] and far["reward"][0] == pytest.approx(-1e4 - 60.0)


def test_a_training_margin_moves_success_and_the_trial_keeps_the_papers_distance():
    """success_mm is training's: 2.5 mm succeeds at the paper's 3 mm and not at a 2 mm margin, and the
    periodic evaluation of a run trained with the margin still scores its trials at 3 mm."""
    from mjendo.paths import TRAINING_CONFIG
    from mjendo.train import trial_env_kwargs
    from mjendo.train_config import load

    tip, origin, axis = np.zeros((1, 3)), np.array([0.0, 0.0, 0.02]), np.array([0.0, 0.0, -1.0])
    args = (tip, tip + np.array([[0.0025, 0, 0]]), origin, axis, np.zeros((1, 3)), np.array([5]), np.array([True]))
    assert mdp.outcome(task_config(env="DE"), *args)["is_success"][0]
    tight = mdp.outcome(task_config(env="DE", success_mm=2.0), *args)
    assert not tight["is_success"][0] and not tight["terminated"][0] and tight["reward"][0] == pytest.approx(-2.5)
    with pytest.raises(ConfigError, match="success_mm"):
        task_config(env="DE", success_mm=0)
    cfg = load("E", TRAINING_CONFIG, variant="paired-precise")
    assert cfg.task_config().success_mm == 2.0
    assert trial_env_kwargs(cfg)["success_mm"] == 3.0 and trial_env_kwargs(cfg)["max_steps"] == 80


def test_the_cpu_task_step_is_the_mdp_of_its_state():
    task = NavigationTask(env="DE", force_obs=True, force_penalty=0.3)
    task.reset(np.random.default_rng(4))
    rng = np.random.default_rng(5)
    for _ in range(6):
        res = task.step(rng.uniform(-0.4, 0.4, 5))
        out = mdp.outcome(task.cfg, task.sim.tip_pos()[None], task.target_pos()[None], task.origin, task.axis,
                          task.contact.force[None], np.array([task.steps]), np.array(["instability" not in res.info]))
        assert res.reward == pytest.approx(float(out["reward"][0]), abs=1e-9)
        assert res.info["reward_force"] == pytest.approx(float(out["reward_force"][0]))
        np.testing.assert_array_equal(res.obs, task.observation())
