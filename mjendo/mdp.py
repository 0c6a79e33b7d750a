"""The MDP's step logic written once, over arrays of environments: reward, termination, observation.

The CPU task (:mod:`mjendo.task`) calls these with one environment (NumPy arrays of shape (1, ...)),
the batched backend (:mod:`mjendo.batch`) with every world (torch tensors of shape (N, ...)). Only
operations that NumPy and torch spell alike are used, so the two backends cannot drift apart.
Inputs are SI (metres, newtons); rewards and observations are millimetres, converted here.
"""

from __future__ import annotations

import math

from mjendo.config import PAPER_BONUS, PAPER_EXIT_X_MM, TaskConfig
from mjendo.units import MM_PER_M

REWARD_TERMS = ("reward_distance", "reward_success", "reward_exit", "reward_force")


def _norm(v):
    return (v * v).sum(-1) ** 0.5


def outcome(cfg: TaskConfig, tip, target, origin, axis, force, steps, ok) -> dict:
    """Distance, success, exit, reward terms, reward, terminated and truncated of every environment.

    ``ok`` is False where the physics diverged this step: such a step neither succeeds nor exits,
    earns reward 0 and truncates the episode.
    """
    delta = target - tip
    dist = _norm(delta) * MM_PER_M
    success = (dist < cfg.success_mm) & ok
    exited = (((tip - origin) * axis).sum(-1) * MM_PER_M < PAPER_EXIT_X_MM) & ok
    force_n = _norm(force)
    live = ok * 1.0
    terms = {
        "reward_distance": -cfg.distance_weight * dist * live,
        "reward_success": PAPER_BONUS * success,
        "reward_exit": -PAPER_BONUS * exited,
        "reward_force": -cfg.force_penalty * force_n * live,
    }
    terminated = success | exited
    if cfg.time_obs:  # the policy sees the time left: the trial's end is a terminal state of its MDP
        terminated = terminated | ((steps >= cfg.max_steps) & ok)
    return {"delta": delta, "distance_mm": dist, "is_success": success, "exited": exited, "force_n": force_n,
            **terms, "reward": sum(terms.values()), "terminated": terminated,
            "truncated": ((steps >= cfg.max_steps) | ~ok) & ~terminated}


def observe(xp, cfg: TaskConfig, delta, tip_vel, cable, prev_axial, contact, force, low, high, scope=None,
            time_left=None, phase=None, step=None, depth=None, normal=None, plan=None, base=None):
    """Observation rows (see task.obs_blocks), clipped to their physical bounds; ``xp`` is numpy or torch.

    ``scope`` (with ``cfg.scope_obs``): insertion (m), tip position from the paper frame's origin (m), tip axis;
    ``time_left`` (with ``cfg.time_obs``): the share of max_steps still left; ``phase`` (with ``cfg.phase_obs``):
    the breathing cycle's phase as a share of the cycle, observed as its sine and cosine (no jump at the wrap);
    ``step`` (with ``cfg.step_obs``): the last step's commanded cable actions and the tip's displacement over it (m);
    ``depth`` (with ``cfg.depth_obs``): the wall's distance along the tip's five rays (m);
    ``normal`` (with ``cfg.normal_obs``): the lumen surface's unit normal at the target, into the lumen;
    ``plan`` (with ``cfg.plan_obs``): the stomach map's plan for the target (mjendo.targets.plan_vector, mm first);
    ``base`` (with ``cfg.residual``): the baseline controller's action the policy's corrects.
    """
    blocks = [delta * MM_PER_M, tip_vel * MM_PER_M, cable * MM_PER_M, prev_axial[:, None] * 1.0]
    if cfg.force_obs:
        reads = 0.0 if cfg.force_off else 1.0  # force_off: the sensor's ablation
        blocks += [contact[:, None] * reads, force * (reads / cfg.force_ref_n)]
    if cfg.scope_obs:
        insertion, tip, axis = scope
        blocks += [insertion[:, None] * MM_PER_M, tip * MM_PER_M, axis * 1.0]
    if cfg.time_obs:
        blocks += [time_left[:, None] * 1.0]
    if cfg.phase_obs:
        angle = 2 * math.pi * phase
        blocks += [xp.sin(angle)[:, None], xp.cos(angle)[:, None]]
    if cfg.step_obs:
        cables, displacement = step
        blocks += [cables * 1.0, displacement * MM_PER_M]
    if cfg.depth_obs:
        blocks += [depth * MM_PER_M]
    if cfg.normal_obs:
        blocks += [normal * 1.0]
    if cfg.plan_obs:
        blocks += [plan * 1.0]
    if cfg.residual:
        blocks += [base * 1.0]
    obs = xp.asarray(xp.concatenate(blocks, 1), dtype=xp.float32)
    return xp.minimum(xp.maximum(obs, low), high)
