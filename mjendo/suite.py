"""dm_control suite-style loader: ``mjendo.suite.load("DE", force_obs=True)``.

The task logic is :class:`mjendo.task.NavigationTask`; this module only
adapts it to dm_control's ``Physics`` / ``Task`` / ``control.Environment``.
"""

from __future__ import annotations

import collections

import numpy as np
from dm_control import mujoco as dm_mujoco  # mjendo's __init__ has chosen the GL backend by now
from dm_control.rl import control
from dm_control.suite import base
from dm_env import specs

from mjendo.config import PAPER_ACTION_LIMIT, task_config
from mjendo.task import NavigationTask, action_size, obs_blocks, obs_options


class Physics(dm_mujoco.Physics):
    """dm_control Physics over the task core's own model and data, with named accessors.

    The core advances the physics (its substeps and periodic load) inside
    ``Task.before_step``, so ``step`` here does nothing more.
    """

    task_core: NavigationTask

    def step(self, nstep: int = 1) -> None:
        del nstep

    def tip_position(self) -> np.ndarray:
        return self.task_core.sim.tip_pos()

    def target_position(self) -> np.ndarray:
        return self.task_core.target_pos()

    def distance_mm(self) -> float:
        return self.task_core.distance_mm()


class Navigation(base.Task):
    """Reach the target on the stomach wall; the MDP lives in the shared core."""

    def __init__(self, core: NavigationTask, random=None):
        super().__init__(random=random)
        self.core = core
        self._last = None

    def initialize_episode(self, physics):
        rng = np.random.default_rng(self.random.randint(2**31))
        self.core.reset(rng)
        self._last = None

    def before_step(self, action, physics):
        self._last = self.core.step(action)

    def action_spec(self, physics):
        n = action_size(self.core.cfg)
        return specs.BoundedArray((n,), np.float64, -PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT, "action")

    def get_observation(self, physics):
        obs = self.core.observation().astype(np.float64)
        out, i = collections.OrderedDict(), 0
        for name, n, _unit, _bounds in obs_blocks(**obs_options(self.core.cfg)):
            out[name] = obs[i:i + n].copy()
            i += n
        return out

    def get_reward(self, physics):
        return 0.0 if self._last is None else self._last.reward

    def get_termination(self, physics):
        r = self._last
        if r is None:
            return None
        if r.terminated:
            return 0.0  # absorbing: success or exit
        if r.truncated:
            return 1.0  # time limit / instability: bootstrap
        return None


def load(env: str = "DE", force_obs: bool = True, fidelity: str = "fast", random=None,
         **task_kwargs) -> control.Environment:
    """A dm_control environment for one of FE, SE, DE, UE1, UE2."""
    core = NavigationTask(task_config(env=env, force_obs=force_obs, fidelity=fidelity, **task_kwargs))
    physics = Physics.from_xml_path(str(core.sim.path))
    physics.task_core = core
    # One model and data for both: the core steps them, dm_control reads them.
    core.sim.model, core.sim.data = physics.model.ptr, physics.data.ptr
    return control.Environment(physics, Navigation(core, random=random), n_sub_steps=core.substeps,
                               time_limit=float("inf"))
