"""Guided starts: training episodes that begin on the map's demonstrator's way, in the real simulator."""

import numpy as np
import pytest

from mjendo import targets
from mjendo.config import ConfigError
from mjendo.demonstrations import GuidedStarts, demo_run
from mjendo.envs import EndoscopeEnv
from mjendo.paths import TRAINING_CONFIG
from mjendo.train import guide_limit, load_config, make_env
from mjendo.units import to_mm


@pytest.fixture(scope="module")
def guided():
    return GuidedStarts(EndoscopeEnv(env="DE", force_obs=True))


def _aided_and_free(env: GuidedStarts) -> tuple[int, int]:
    task = env.unwrapped.task
    aided = task.targets[task.contact_aided]
    free = task.targets[~task.contact_aided]
    return int(aided[0]), int(free[0])


def test_an_episode_at_a_contact_aided_target_begins_on_its_demonstrators_way(guided):
    task = guided.unwrapped.task
    aided, _ = _aided_and_free(guided)
    meta = targets.read_map(targets.TARGETS_FILE)
    recorded = next(p["demos"] for p in meta["points"] if p["id"] == aided)
    guided.set_guide_steps(30)
    begun = []
    for seed in range(12):
        guided_obs, guided_info = guided.reset(seed=seed, options={"target_index": aided})
        steps = task.steps
        begun.append(steps)
        if steps == 0:
            continue
        demo = targets.DEMOS[recorded[demo_run("DE", task.start_index, len(task.start_states))]]
        # Full-speed insertion all the way: the scope is 2.5 mm deeper per guided step.
        assert to_mm(task.insertion) == pytest.approx(2.5 * steps, abs=1e-6)
        assert guided_info["guided_steps"] == steps and task.target == aided
        np.testing.assert_allclose(guided_obs, task.observation(), atol=1e-5)
        expected_pulls = sum(targets.demo_action(demo, k)[:4] for k in range(steps)) * task.cable_step
        np.testing.assert_allclose(task.pulls, np.clip(expected_pulls, -task.sim.cable_pull_max,
                                                       task.sim.cable_pull_max), atol=1e-9)
    assert max(begun) > 5 and min(begun) < max(begun) <= 30  # drawn, not fixed, and never past the limit


def test_free_targets_and_a_zero_limit_start_unguided(guided):
    aided, free = _aided_and_free(guided)
    guided.set_guide_steps(30)
    for seed in range(4):
        guided.reset(seed=seed, options={"target_index": free})
        assert guided.unwrapped.task.steps == 0
    guided.set_guide_steps(0)
    for seed in range(4):
        guided.reset(seed=seed, options={"target_index": aided})
        assert guided.unwrapped.task.steps == 0


def test_the_guide_limit_falls_to_zero_and_only_training_episodes_are_guided():
    cfg = load_config("E", TRAINING_CONFIG, "short-horizon-guided")
    assert cfg.guide_steps == 40 and cfg.guide_decay_steps == 200_000
    assert [guide_limit(cfg, t) for t in (0, 100_000, 200_000, 300_000)] == [40, 20, 0, 0]
    assert guide_limit(load_config("E", TRAINING_CONFIG, "paper"), 0) == 0  # the paper's E is never guided
    assert isinstance(make_env(cfg, 0)().env, GuidedStarts)
    assert not isinstance(make_env(load_config("E", TRAINING_CONFIG), 0)().env, GuidedStarts)
    with pytest.raises(ConfigError, match="guide_steps and guide_decay_steps must be >= 0"):
        load_config("E", TRAINING_CONFIG, "short-horizon-guided", guide_steps=-1)
    cfg.task = {**cfg.task, "version": 0}
    with pytest.raises(ConfigError, match="task version 0 .* has none of"):
        cfg.check()


def test_each_start_state_takes_the_demonstrator_of_the_nearest_recorded_phase():
    n = 40
    assert [demo_run("DE", p * n // targets.PHASES, n) for p in range(targets.PHASES)] == [1, 2, 3, 4]
    assert demo_run("DE", n - 1, n) == 1  # the cycle wraps round to phase 0
    assert demo_run("SE", 17, n) == 0

