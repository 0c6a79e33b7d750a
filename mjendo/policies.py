"""Controllers that act in the task: shipped/trained PPO policies, the DLS baseline, random.

Every controller has ``reset(task)`` and ``act(obs, task) -> action`` so the
evaluation and the viewer treat them alike.
"""

from __future__ import annotations

import json
import os
import pickle
from pathlib import Path

import numpy as np

from mjendo.anatomy import MODELS
from mjendo.config import ConfigError
from mjendo.task import NavigationTask, action_scales, obs_size

# Shipped policies; MJENDO_POLICIES points evaluation and viewer at another set.
POLICIES_DIR = Path(os.environ.get("MJENDO_POLICIES", MODELS / "policies"))
POLICY_NAMES = ("A", "B", "C", "D", "E")
MODEL_FILE = "model.zip"
NORM_FILE = "vecnormalize.pkl"
META_FILE = "meta.json"


class PolicyError(ValueError):
    """A policy cannot be loaded or does not fit the task; the message says what to do."""


class PPOController:
    """A trained stable-baselines3 PPO policy with its observation normalisation."""

    def __init__(self, directory: Path):
        from stable_baselines3 import PPO

        directory = Path(directory)
        path = directory / MODEL_FILE
        if not path.exists():
            raise PolicyError(f"no policy file at {path}: train it with `make train POLICY=...` or pass "
                              "a directory holding model.zip")
        try:
            self.model = PPO.load(str(path), device="cpu")
        except Exception as exc:  # zip/pickle/torch errors
            raise PolicyError(f"cannot load {path}: {exc}; the file is corrupt or not an SB3 PPO model") from exc
        self.obs_rms, self.clip_obs = None, 10.0
        norm = directory / NORM_FILE
        if norm.exists():
            try:
                with open(norm, "rb") as f:
                    vn = pickle.load(f)
            except Exception as exc:
                raise PolicyError(f"cannot read {norm}: {exc}") from exc
            self.obs_rms, self.clip_obs = vn.obs_rms, vn.clip_obs
        meta = directory / META_FILE
        self.meta = json.loads(meta.read_text()) if meta.exists() else {}
        self.name = self.meta.get("policy", directory.name)
        self.n_obs = int(self.model.observation_space.shape[0])

    def check(self, task: NavigationTask) -> None:
        if self.n_obs != obs_size(task.cfg.force_obs):
            raise PolicyError(f"policy {self.name} expects {self.n_obs} observations but the task gives "
                              f"{obs_size(task.cfg.force_obs)}: use force_obs={self.n_obs == obs_size(True)}")
        trained = self.meta.get("action_scales")
        now = action_scales(task.cfg)
        if trained is not None and trained != now:
            diff = ", ".join(f"{k} {trained.get(k)} (task: {v})" for k, v in now.items() if trained.get(k) != v)
            raise PolicyError(f"policy {self.name} was trained with other action scales: {diff}; retrain it with "
                              "`make train` or build the task with the policy's values")

    def reset(self, task: NavigationTask) -> None:
        self.check(task)

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        if self.obs_rms is None:
            return obs
        o = (obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + 1e-8)
        return np.clip(o, -self.clip_obs, self.clip_obs).astype(np.float32)

    def act(self, obs, task: NavigationTask) -> np.ndarray:
        action, _ = self.model.predict(self.normalize(np.asarray(obs, np.float32)), deterministic=True)
        return action


class RandomController:
    name = "random"

    def __init__(self, seed: int = 0):
        self.rng = np.random.default_rng(seed)

    def reset(self, task: NavigationTask) -> None:
        pass

    def act(self, obs, task: NavigationTask) -> np.ndarray:
        return self.rng.uniform(-0.4, 0.4, 5)


def force_obs_of(spec: str) -> bool:
    """Whether the controller named by ``spec`` needs the force-aware observation."""
    if spec in POLICY_NAMES:
        from mjendo.train import load_config  # the training config says what each policy observes

        return bool(load_config(spec)["force_obs"])
    p = Path(spec)
    if p.is_dir() or p.suffix == ".zip":
        return PPOController(p.parent if p.suffix == ".zip" else p).n_obs == obs_size(True)
    return True  # baseline, random: they ignore the observation's force part


def load_controller(spec: str, task: NavigationTask | None = None):
    """'A'..'E' (shipped), 'baseline', 'random', or a directory holding model.zip."""
    if spec in POLICY_NAMES:
        ctrl = PPOController(POLICIES_DIR / spec)
    elif spec == "baseline":
        from mjendo.baseline import DLSController

        if task is None:
            raise ConfigError("the baseline controller needs the task it will drive")
        ctrl = DLSController(task)
    elif spec == "random":
        ctrl = RandomController()
    elif Path(spec).is_dir() or Path(spec).suffix == ".zip":
        p = Path(spec)
        ctrl = PPOController(p.parent if p.suffix == ".zip" else p)
    else:
        raise ConfigError(f"unknown policy {spec!r}; valid: {', '.join(POLICY_NAMES)}, baseline, random, "
                          "or a directory with model.zip")
    if task is not None and hasattr(ctrl, "check"):
        ctrl.check(task)
    return ctrl


def rollout(env, ctrl, seed: int = 0, target: int | None = None) -> dict:
    """Run one episode of ``ctrl`` in a Gymnasium ``EndoscopeEnv``; returns the last step's info."""
    obs, info = env.reset(seed=seed, options={"target_index": target} if target is not None else None)
    ctrl.reset(env.task)
    while True:
        obs, _, term, trunc, info = env.step(ctrl.act(obs, env.task))
        if term or trunc:
            return info
