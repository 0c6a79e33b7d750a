"""Start a policy that observes more (the contact force ``force_obs``, the scope's state ``scope_obs``, the time
left ``time_obs``, the breathing phase ``phase_obs``, the last step ``step_obs``, the wall's depth ``depth_obs``, the
target's surface normal ``normal_obs``, the map's plan ``plan_obs``) from a trained one that does not.

The added inputs come last in the observation (task.OBS_OPTIONS' order), so the source's first-layer weights
are kept and the new inputs' weights start at zero: the widened policy and value function compute exactly
what the source computed (function-preserving widening, as Net2Net) until training gives the new inputs
weight. A policy that must learn from scratch to use the scope's state would first have to relearn the wall.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

from mjendo.config import ConfigError

# Rollout steps of the source policy from which the new inputs' normalisation starts: enough for a few
# whole episodes on each environment, so insertion depth, tip pose and time are seen over their range.
STAT_STEPS = 2048


def widen_state(source: dict, target: dict, n_source: int, scale: float = 0.0, seed: int = 0) -> dict:
    """``target``'s state dict with ``source``'s tensors; first-layer weights padded with new columns: zero, or
    normal at ``scale`` times the standard deviation of the layer's old weights (TrainConfig.widen_scale)."""
    import torch

    out = {}
    gen = torch.Generator().manual_seed(seed)
    for name, new in target.items():
        old = source[name]
        if old.shape == new.shape:
            out[name] = old.clone()
        elif old.dim() == 2 and old.shape[0] == new.shape[0] and old.shape[1] == n_source < new.shape[1]:
            out[name] = new.new_zeros(new.shape)
            out[name][:, :n_source] = old
            if scale:
                noise = torch.randn(new.shape[0], new.shape[1] - n_source, generator=gen, dtype=new.dtype)
                out[name][:, n_source:] = noise * (scale * float(old.std()))
        else:
            raise ConfigError(f"cannot widen parameter {name}: source shape {tuple(old.shape)}, "
                              f"new shape {tuple(new.shape)} (the two policies' networks differ, not only "
                              "their observation)")
    return out


def widened_normalizer(norm_file: Path, venv, gamma: float, model):
    """A VecNormalize over ``venv`` with the source's statistics for its inputs and the new inputs'
    measured over STAT_STEPS steps of ``model`` (which acts as the source does)."""
    from stable_baselines3.common.vec_env import VecNormalize

    with open(norm_file, "rb") as f:
        src = pickle.load(f)  # VecNormalize.load would refuse the wider observation space
    norm = VecNormalize(venv, gamma=gamma, clip_obs=src.clip_obs, clip_reward=src.clip_reward)
    n = src.obs_rms.mean.shape[0]
    norm.obs_rms.mean[:n], norm.obs_rms.var[:n] = src.obs_rms.mean, src.obs_rms.var
    norm.ret_rms = src.ret_rms
    norm.training = False  # measure the new inputs without moving the source's statistics
    obs, raw = norm.reset(), []
    for _ in range(max(1, STAT_STEPS // venv.num_envs)):
        action, _ = model.predict(obs, deterministic=False)
        obs, *_ = norm.step(action)
        raw.append(norm.get_original_obs()[:, n:])
    raw = np.concatenate(raw)
    norm.obs_rms.mean[n:], norm.obs_rms.var[n:] = raw.mean(0), np.maximum(raw.var(0), 1e-6)
    norm.obs_rms.count = src.obs_rms.count
    norm.training = True
    return norm
