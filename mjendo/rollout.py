"""The episode loop, written once: evaluation, the viewer, training's evaluations and tests iterate it."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np


@dataclass
class Step:
    """One transition of an episode; ``index`` 0 is the reset (no action, no reward yet)."""

    index: int
    obs: np.ndarray
    action: np.ndarray | None
    reward: float
    terminated: bool
    truncated: bool
    info: dict

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated


def episode(env, ctrl, seed: int | None = None, target: int | None = None,
            anatomy_index: int | None = None) -> Iterator[Step]:
    """Reset ``env`` (an EndoscopeEnv) and run ``ctrl`` until the episode terminates or is truncated.

    Yields the reset first (index 0), then every step. ``target`` aims the episode at one target of the
    condition's list; ``anatomy_index`` picks the stomach of an environment drawing from a set.
    """
    options = {k: v for k, v in (("target_index", target), ("anatomy_index", anatomy_index)) if v is not None} \
        or None
    obs, info = env.reset(seed=seed, options=options)
    ctrl.reset(env.task)
    yield Step(0, obs, None, 0.0, False, False, {**info, "step": 0})
    k = 0
    while True:
        k += 1
        action = ctrl.act(obs, env.task)
        obs, reward, terminated, truncated, info = env.step(action)
        yield Step(k, obs, action, float(reward), bool(terminated), bool(truncated), info)
        if terminated or truncated:
            return


def run(env, ctrl, seed: int | None = None, target: int | None = None) -> tuple[dict, float]:
    """One whole episode: the last step's info and the episode's return."""
    total, last = 0.0, None
    for s in episode(env, ctrl, seed, target):
        total += s.reward
        last = s
    return last.info, total
