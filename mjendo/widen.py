"""Start a policy that observes more (the contact force ``force_obs``, the scope's state ``scope_obs``, the time
left ``time_obs``, the breathing phase ``phase_obs``, the last step ``step_obs``, the wall's depth ``depth_obs``, the
target's surface normal ``normal_obs``, the map's plan ``plan_obs``) from a trained one that does not.

The added inputs come last in the observation (task.OBS_OPTIONS' order), so the source's first-layer weights
are kept and the new inputs' weights start at zero: the widened policy and value function compute exactly
what the source computed (function-preserving widening, as Net2Net) until training gives the new inputs
weight. A policy that must learn from scratch to use the scope's state would first have to relearn the wall.
The hidden layers can grow the same way (a wider ``ppo.net_arch`` than the source's): the new units take fresh
incoming weights and start with zero outgoing ones, so they too change nothing until training weighs them.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

from mjendo.config import ConfigError

# Rollout steps of the source policy from which the new inputs' normalisation starts: enough for a few
# whole episodes on each environment, so insertion depth, tip pose and time are seen over their range.
STAT_STEPS = 2048
GROWTH = ("a fine-tune can add inputs and widen the hidden layers, not remove inputs or units, nor add or remove "
          "layers: give ppo.net_arch as many layers as the source's, each as wide or wider")


def widen_state(source: dict, target: dict, n_source: int, scale: float = 0.0, seed: int = 0) -> dict:
    """``target``'s state dict holding ``source``'s tensors in its leading rows and columns. New columns (new inputs,
    or new units of the layer below) start at zero, or for a first layer's new inputs normal at ``scale`` times the
    spread of its old weights (TrainConfig.widen_scale); new rows (new units) keep ``target``'s fresh init."""
    import torch

    out = {}
    gen = torch.Generator().manual_seed(seed)
    unmatched = sorted(set(source) ^ set(target))  # a layer added or removed
    if unmatched:
        name = unmatched[0]
        have = tuple(source[name].shape) if name in source else "none"
        want = tuple(target[name].shape) if name in target else "none"
        raise ConfigError(f"cannot widen parameter {name}: source shape {have}, new shape {want} ({GROWTH})")
    for name, new in target.items():
        old = source[name]
        if old.shape == new.shape:
            out[name] = old.clone()
            continue
        if old.dim() != new.dim() or any(o > w for o, w in zip(old.shape, new.shape, strict=True)):
            raise ConfigError(f"cannot widen parameter {name}: source shape {tuple(old.shape)}, new shape "
                              f"{tuple(new.shape)} ({GROWTH})")
        grown = new.clone()
        if old.dim() == 2:
            rows, cols = old.shape
            grown[:rows] = 0.0
            grown[:rows, :cols] = old
            if scale and cols == n_source < new.shape[1]:
                noise = torch.randn(rows, new.shape[1] - cols, generator=gen, dtype=new.dtype)
                grown[:rows, cols:] = noise * (scale * float(old.std()))
        else:
            grown[: old.shape[0]] = old
        out[name] = grown
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
