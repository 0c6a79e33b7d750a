"""Training's target draw: prioritised on what the policy fails within a trial, phased curriculum, resume."""

import json

import numpy as np
import pytest

from mjendo.config import PAPER_EVAL_STEPS, ConfigError
from mjendo.sampling import FLOOR, TargetSampler


def test_adaptive_draws_failed_and_slow_targets_more_often_than_solved_ones():
    s = TargetSampler([10, 11, 12], [False, True, True], "adaptive")
    for _ in range(30):
        s.record(10, True, 40)  # solved within a trial
        s.record(11, True, PAPER_EVAL_STEPS + 20)  # reached, but too slowly for a trial
        s.record(12, False, 128)
    w = s.weights(0)
    assert w[0] == pytest.approx(FLOOR, abs=0.01)
    assert w[1] == pytest.approx(w[2]) == pytest.approx(1 + FLOOR, abs=0.01)
    s.record(99, True, 10)  # not in the list: ignored
    assert np.allclose(s.weights(0), w)


def test_uniform_is_the_papers_draw_and_the_curriculum_multiplies_in():
    uniform = TargetSampler([1, 2], [False, True])
    assert not uniform.active and np.all(uniform.weights(10**6) == 1.0)
    cur = TargetSampler([1, 2], [False, True], "adaptive", curriculum_steps=1000)
    assert cur.active
    assert cur.weights(0)[1] == 0.0 and cur.weights(500)[1] == pytest.approx(0.5 * cur.weights(500)[0])
    with pytest.raises(ConfigError, match="target_sampling"):
        TargetSampler([1], [False], "greedy")


def test_solve_rates_survive_a_checkpoint_of_the_same_list_only(tmp_path):
    s = TargetSampler([1, 2], [False, True], "adaptive")
    s.record(1, True, 5)
    s.save(tmp_path / "s.json")
    back = TargetSampler([1, 2], [False, True], "adaptive")
    back.load(tmp_path / "s.json")
    assert np.allclose(back.weights(0), s.weights(0))
    other = TargetSampler([1, 3], [False, True], "adaptive")
    other.load(tmp_path / "s.json")  # another list: starts afresh
    assert np.all(other.solved == 0)
    assert json.loads((tmp_path / "s.json").read_text())["targets"] == [1, 2]


def test_a_joined_pool_draws_each_list_half_the_time_and_evaluations_keep_the_envs_list():
    from mjendo import targets
    from mjendo.config import task_config
    from mjendo.paths import TRAINING_CONFIG
    from mjendo.train import load_config, make_env, target_sampler

    cfg = load_config("E", TRAINING_CONFIG, "free-pool")
    table = targets.load(1)
    a, f = set(table.lists["A"]), set(table.lists["F"])
    sampler = target_sampler(cfg)
    assert len(sampler.targets) == len(a | f) and sampler.active
    w = sampler.weights(0)
    in_a = np.array([t in a for t in sampler.targets])
    assert w[in_a].sum() / w.sum() == pytest.approx(0.5, abs=0.02)  # 65 targets as often as 813 (a few in both)
    assert cfg.task_config().target_list is None  # periodic evaluations and meta.json: the env's own list A
    env = make_env(cfg, 0)()
    assert set(env.unwrapped.task.targets.tolist()) == a | f
    env.unwrapped.set_target_weights(w)
    drawn = [env.reset(seed=s)[1]["target_index"] for s in range(200)]
    assert 0.35 < np.mean([t in a for t in drawn]) < 0.65
    with pytest.raises(ConfigError, match="unknown target_list 'A\\+A'"):
        task_config(target_list="A+A")
    with pytest.raises(ConfigError, match="unknown target_list 'A\\+Q'"):
        task_config(target_list="A+Q")


def test_each_stomach_of_a_set_draws_its_own_joined_pool_half_and_half():
    # Across stomachs the pool is each stomach's own list A and list F (training's sampler holds no list):
    # the task itself draws each list equally often, and clearing the weights keeps that draw.
    from mjendo import anatomy, targets
    from mjendo.envs import EndoscopeEnv
    from mjendo.paths import TRAINING_CONFIG
    from mjendo.train import load_config, target_sampler

    cfg = load_config("E", TRAINING_CONFIG, "randomized-free-pool")
    assert cfg.task["anatomy"] == "train" and cfg.train_targets == "A+F" and not target_sampler(cfg).active
    env = EndoscopeEnv("SE", anatomy="train", target_list="A+F")
    table = targets.load(1, targets.map_path(anatomy.stomach_dir(env.anatomies[3])))
    a = set(table.lists["A"])
    assert len(a) < len(table.lists["F"]) / 2  # uniform over the union would draw list A under a third of the time
    task = env.anatomy_task(3)
    task.set_target_weights(None)
    rng = np.random.default_rng(5)
    drawn = [task.reset(rng) is not None and task.target for _ in range(300)]
    assert 0.4 < np.mean([t in a for t in drawn]) < 0.6
    env.close()


def test_across_a_set_the_draw_weighs_pairs_of_stomach_and_target(tmp_path):
    # Prioritised level replay over the training stomachs: a (stomach, target) pair the policy fails is drawn
    # more often than one of the same list it solves, every stomach as often before any episode, and the env
    # draws the stomach and then the target by the per-stomach weights, naming the stomach in every step's info.
    from mjendo.envs import EndoscopeEnv
    from mjendo.paths import TRAINING_CONFIG
    from mjendo.train import load_config, target_sampler

    cfg = load_config("E", TRAINING_CONFIG, "randomized-free-pool", target_sampling="adaptive")
    sampler = target_sampler(cfg)
    assert sampler.active and len(sampler.sizes) == 20 and sum(sampler.sizes) == len(sampler.targets)
    assert np.allclose([x.sum() for x in sampler.env_weights(0)], sampler.env_weights(0)[0].sum())
    start = sum(sampler.sizes[:3])
    group = range(start, start + sampler.sizes[3])
    i, j = [k for k in group if sampler.base[k] == sampler.base[start]][:2]
    for _ in range(30):
        sampler.record(sampler.targets[i], False, 128)
        sampler.record(sampler.targets[j], True, 30)
    w = sampler.weights(0)
    assert w[i] / w[j] == pytest.approx((1 + FLOOR) / FLOOR, rel=0.01)
    sampler.save(tmp_path / "s.json")  # a resumed run draws as the killed one did
    back = target_sampler(cfg)
    back.load(tmp_path / "s.json")
    assert np.allclose(back.weights(0), w)

    env = EndoscopeEnv("SE", anatomy="train", target_list="A+F")
    only = [np.zeros(n) for n in sampler.sizes]
    only[3][i - start] = 1.0
    env.set_target_weights(only)
    drawn = {(info["anatomy"], info["target_index"]) for info in (env.reset(seed=s)[1] for s in range(5))}
    assert drawn == {sampler.targets[i]}
    assert env.step(np.zeros(5))[4]["anatomy"] == sampler.targets[i][0] == env.anatomies[3]
    env.set_target_weights(None)  # back to every stomach alike and each stomach's own draw
    assert len({env.reset(seed=s)[1]["anatomy"] for s in range(12)}) >= 5
    with pytest.raises(ValueError, match="one array per stomach"):
        env.set_target_weights(only[:5])
    env.close()
