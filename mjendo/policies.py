"""Controllers that act in the task: trained PPO policies, the DLS baseline, random.

Every controller has ``reset(task)`` and ``act(obs, task) -> action`` so the
evaluation, the viewer and training's periodic evaluation treat them alike
(:mod:`mjendo.rollout` runs them). Policy folders are read by
:mod:`mjendo.artifacts`.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from mjendo import artifacts
from mjendo.artifacts import PolicyError
from mjendo.config import CURRENT_VERSION, PAPER_ACTION_LIMIT, ConfigError
from mjendo.task import (
    ACTION_SCALE_FIELDS,
    OBS_OPTIONS,
    SIZE_OPTIONS,
    NavigationTask,
    action_size,
    obs_options,
    obs_size,
)

__all__ = ["PPOController", "PolicyError", "RandomController", "force_obs_of", "load_controller", "obs_options_of"]


class PPOController:
    """A trained stable-baselines3 PPO policy with its observation normalisation."""

    def __init__(self, policy: artifacts.Policy):
        self.policy = policy
        self.model = policy.model
        self.meta = policy.meta
        self.name = policy.name
        self.n_obs = policy.n_obs

    @classmethod
    def from_folder(cls, directory: Path) -> PPOController:
        return cls(artifacts.load(directory))

    @classmethod
    def from_training(cls, model, venv, meta: dict) -> PPOController:
        """The policy being trained, with the training env's current normalisation (periodic evaluation)."""
        rms = getattr(venv, "obs_rms", None)
        return cls(artifacts.Policy(Path("."), model, rms, float(getattr(venv, "clip_obs", 10.0)),
                                    float(getattr(venv, "epsilon", 1e-8)), meta))

    def check(self, task: NavigationTask) -> None:
        """Refuse a task whose observation or action meaning differs from the one the policy trained in."""
        given = obs_size(**obs_options(task.cfg))
        if self.n_obs != given:
            combos = [dict(zip(SIZE_OPTIONS, on, strict=True))
                      for on in itertools.product((False, True), repeat=len(SIZE_OPTIONS))]
            fits = [", ".join(f"{k}={v}" for k, v in on.items()) for on in combos if obs_size(**on) == self.n_obs]
            raise PolicyError(f"policy {self.name} expects {self.n_obs} observations but the task gives {given}: "
                              f"use {' or '.join(fits) or 'the task the policy was trained in'}")
        trained = artifacts.trained_task(self.meta)
        trained_space = bool(trained.get("task_space", False))
        if trained_space != task.cfg.task_space:
            what = "a tip displacement" if trained_space else "cable and insertion commands"
            raise PolicyError(f"policy {self.name} acts by {what} (task_space={trained_space}), the task has "
                              f"task_space={task.cfg.task_space}: build the task with the policy's setting")
        if int(trained["version"]) != task.cfg.version:
            raise PolicyError(f"policy {self.name} was trained in task version {trained['version']}, the task is "
                              f"version {task.cfg.version}: build the task with version={trained['version']} "
                              "(ids mjendo/<env>-v" f"{trained['version']}) or use a policy of this version")
        diff = [f"{k} {trained[k]} (task: {getattr(task.cfg, k)})" for k in ACTION_SCALE_FIELDS
                if k in trained and float(trained[k]) != float(getattr(task.cfg, k))]
        if diff:
            raise PolicyError(f"policy {self.name} was trained with other action scales: {', '.join(diff)}; "
                              "retrain it with `make train` or build the task with the policy's values")

    def reset(self, task: NavigationTask) -> None:
        self.check(task)

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        """What SB3's VecNormalize.normalize_obs does with the same statistics (tested against it)."""
        p = self.policy
        if p.obs_rms is None:
            return obs
        o = (obs - p.obs_rms.mean) / np.sqrt(p.obs_rms.var + p.epsilon)
        return np.clip(o, -p.clip_obs, p.clip_obs).astype(np.float32)

    def act(self, obs, task: NavigationTask | None) -> np.ndarray:
        """The actor's mean clipped to the action box, for one observation or a batch (n, n_obs): what
        ``model.predict(deterministic=True)`` returns, a third of its cost (it builds a distribution every call),
        which the evaluation and the study pay per step."""
        import torch

        pol = self.model.policy
        obs = np.asarray(obs, np.float32)
        with torch.no_grad():
            x = torch.as_tensor(self.normalize(obs)).reshape(-1, self.n_obs)
            mean = pol.action_net(pol.mlp_extractor.forward_actor(pol.extract_features(x, pol.pi_features_extractor)))
        space = self.model.action_space
        action = np.clip(mean.numpy(), space.low, space.high)
        return action if obs.ndim == 2 else action[0]


class RandomController:
    name = "random"

    def __init__(self, seed: int = 0):
        self.rng = np.random.default_rng(seed)

    def reset(self, task: NavigationTask) -> None:
        pass

    def act(self, obs, task: NavigationTask) -> np.ndarray:
        return self.rng.uniform(-PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT, action_size(task.cfg))


NON_LEARNED = ("baseline", "random")


def obs_options_of(spec: str) -> dict[str, bool]:
    """The observation options (task.OBS_OPTIONS) the controller named by ``spec`` needs (its own folder)."""
    if spec in NON_LEARNED:  # they ignore the observation's force part
        return {k: k == "force_obs" for k in OBS_OPTIONS}
    return artifacts.obs_options(artifacts.resolve(spec))


def force_obs_of(spec: str) -> bool:
    """Whether the controller named by ``spec`` needs the force-aware observation."""
    return obs_options_of(spec)["force_obs"]


def version_of(spec: str, default: int = CURRENT_VERSION) -> int:
    """The task version the controller named by ``spec`` was trained in (non-learned ones act in any)."""
    if spec in NON_LEARNED:
        return default
    return int(artifacts.trained_task(artifacts.read_meta(artifacts.resolve(spec)))["version"])


def load_controller(spec: str, task: NavigationTask | None = None):
    """'A'..'E' (shipped), 'baseline', 'random', or a policy folder (or its model.zip)."""
    if spec == "baseline":
        from mjendo.baseline import DLSController

        if task is None:
            raise ConfigError("the baseline controller needs the task it will drive")
        ctrl = DLSController(task)
    elif spec == "random":
        ctrl = RandomController()
    else:
        ctrl = PPOController.from_folder(artifacts.resolve(spec))
    if task is not None and hasattr(ctrl, "check"):
        ctrl.check(task)
    return ctrl
