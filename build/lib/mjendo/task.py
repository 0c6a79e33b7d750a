"""The navigation MDP, written once: state, observation, reward, termination, targets.

Both the Gymnasium env (:mod:`mjendo.envs`) and the dm_control task
(:mod:`mjendo.suite`) drive this class; neither adds task logic of its own.
Physics is SI inside; observations, rewards and reports are in millimetres,
converted only here through :mod:`mjendo.units`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import mujoco
import numpy as np

from mjendo import anatomy
from mjendo.config import (
    ACTION_SIZE,
    CONDITIONS,
    PAPER_ACTION_LIMIT,
    PAPER_BONUS,
    PAPER_EXIT_X_MM,
    PAPER_SUCCESS_MM,
    TaskConfig,
    substeps,
    task_config,
)
from mjendo.sim import InstabilityError, Simulator
from mjendo.units import from_mm, to_mm

# (name, size, unit, bound) of each observation block, in order. The bounds are physical: the
# scene is well inside 1 m, a tip faster than 5 m/s or a force over 100 N is a numerical event,
# and observations are clipped to them (the observation space says so).
OBS_BLOCKS = [("ee_to_target", 3, "mm", (-1000.0, 1000.0)), ("ee_velocity", 3, "mm/s", (-5000.0, 5000.0)),
              ("cable_lengths", 4, "mm", (0.0, 500.0)),
              ("previous_axial_action", 1, "action units", (-PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT))]
FORCE_BOUND_N = 100.0
FORCE_BLOCKS = [("contact", 1, "0/1", (0.0, 1.0)), ("force", 3, "N / force_ref_n", (-FORCE_BOUND_N, FORCE_BOUND_N))]
SETTLE_S = 1.0  # the stomach settles under gravity (and load) before episodes start
# Start states are snapshots of the stomach in its periodic steady state, this
# many per load cycle (every 50 ms of a 4 s cycle): an episode starts at its
# drawn phase without a transient (docs/physics.md "Episode start").
PHASES_PER_CYCLE = 80

TARGET_WHITE = (1.0, 1.0, 1.0, 1.0)
TARGET_YELLOW = (1.0, 0.85, 0.0, 1.0)


# What an action means physically; a policy trained under other values would misbehave.
ACTION_SCALE_FIELDS = ("control_period_s", "cable_mm_per_unit", "insertion_mm_per_unit")


def obs_blocks(force_obs: bool) -> list[tuple]:
    return OBS_BLOCKS + (FORCE_BLOCKS if force_obs else [])


def obs_size(force_obs: bool) -> int:
    return sum(b[1] for b in obs_blocks(force_obs))


def obs_bounds(cfg: TaskConfig) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bound of every observation entry (the force block in units of force_ref_n)."""
    lo, hi = [], []
    for name, n, _unit, (a, b) in obs_blocks(cfg.force_obs):
        scale = 1.0 / cfg.force_ref_n if name == "force" else 1.0
        lo += [a * scale] * n
        hi += [b * scale] * n
    return np.array(lo, np.float32), np.array(hi, np.float32)


@lru_cache(maxsize=4)
def free_targets(fidelity: str) -> np.ndarray:
    """Where the wall would be (FE): every lumen vertex of the settled static stomach."""
    sim = Simulator("SE", fidelity)
    sim.set_controls(np.zeros(4), sim.insertion_range[0])  # scope out of the way
    sim.step(int(round(SETTLE_S / sim.model.opt.timestep)))
    return sim.vertices()


@dataclass
class StepResult:
    obs: np.ndarray
    reward: float
    terminated: bool
    truncated: bool
    info: dict = field(default_factory=dict)


class NavigationTask:
    """Reach a target vertex on the stomach wall with the endoscope tip."""

    def __init__(self, cfg: TaskConfig | None = None, **kw):
        self.cfg = cfg if cfg is not None else task_config(**kw)
        c = self.cfg
        self.sim = Simulator(c.env, c.fidelity)
        self.stomach = anatomy.load()
        listname = c.target_list or CONDITIONS[c.env].target_list
        self.target_list = listname
        self.targets = np.array(self.stomach.targets_a if listname == "A" else self.stomach.targets_b)
        self.cable_step = from_mm(c.cable_mm_per_unit)
        self.insertion_step = from_mm(c.insertion_mm_per_unit)
        self.substeps = substeps(c)
        self.obs_size = obs_size(c.force_obs)
        self.obs_low, self.obs_high = obs_bounds(c)
        self.control_dt = self.substeps * self.sim.model.opt.timestep
        # Paper's frame: x along the insertion axis, origin 15 mm outside the
        # cardia, so "x_EE < 15 mm" means the tip is back behind the cardia.
        self.axis = self.stomach.axis
        self.origin = self.stomach.entry - from_mm(PAPER_EXIT_X_MM) * self.axis
        self._fe_targets = None if self.sim.has_stomach else free_targets(c.fidelity)
        self._starts = self._settle()
        self._settled = self._starts[0]
        self.target = int(self.targets[0])
        self.pulls = np.zeros(4)
        self.insertion = 0.0
        self.prev_axial = 0.0
        self.steps = 0
        self.peak_force = 0.0
        self.contact = self.sim.contact()  # a valid reading before the first reset (dm_env asks specs first)

    # ------------------------------------------------------------- episodes
    def _settle(self) -> list[np.ndarray]:
        """Start states: the settled stomach at phase 0, and under a periodic load one per phase.

        The load runs one full cycle to reach its periodic steady state (the
        wall settles within about 0.5 s of each switch), then the next cycle
        is recorded; each snapshot keeps its own time, so the load's phase
        is right after a reset.
        """
        sim = self.sim
        sim.reset()
        sim.set_controls(np.zeros(4), 0.0)
        dt = sim.model.opt.timestep
        sim.step(int(round(SETTLE_S / dt)))
        if not sim.f0:
            return [self._get_state()]
        cycle = int(round(2 * sim.half_period / dt))
        every = max(1, cycle // PHASES_PER_CYCLE)
        sim.step(cycle - int(round(SETTLE_S / dt)) % cycle)  # whole cycles since t = 0: phase 0
        starts = []
        for _ in range(cycle // every):
            starts.append(self._get_state())
            sim.step(every)
        return starts

    def _get_state(self) -> np.ndarray:
        m, d = self.sim.model, self.sim.data
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mujoco.mj_stateSize(m, spec))
        mujoco.mj_getState(m, d, state, spec)
        return state

    def reset(self, rng: np.random.Generator) -> np.ndarray:
        """Start an episode: settled stomach, straight scope, a random target."""
        sim = self.sim
        k = int(rng.integers(len(self._starts))) if self.cfg.randomize_phase else 0
        mujoco.mj_setState(sim.model, sim.data, self._starts[k], mujoco.mjtState.mjSTATE_INTEGRATION)
        sim.clear_warnings()  # counts belong to the previous episode
        self.pulls[:] = 0.0
        self.insertion = 0.0
        self.prev_axial = 0.0
        self.steps = 0
        self.peak_force = 0.0
        sim.set_controls(self.pulls, self.insertion)
        mujoco.mj_forward(sim.model, sim.data)
        self.contact = sim.contact()
        return self.set_target(int(rng.choice(self.targets)))

    def set_target(self, index: int) -> np.ndarray:
        """Aim at another vertex of the list (e.g. to replay a chosen target); returns the observation."""
        if index not in set(self.targets.tolist()):
            raise ValueError(f"target {index} is not in target list {self.target_list}: {self.targets.tolist()}")
        self.target = int(index)
        self._mark_target(False)
        mujoco.mj_kinematics(self.sim.model, self.sim.data)  # place the moved marker for the first frame
        return self.observation()

    def target_pos(self) -> np.ndarray:
        """Target position now (m): it moves with the wall in DE/UE."""
        if self._fe_targets is not None:
            return self._fe_targets[self.target].copy()
        return self.sim.vertices([self.target])[0]

    def tip_x_mm(self) -> float:
        """Tip coordinate along the insertion axis in the paper's frame (mm)."""
        return float(to_mm((self.sim.tip_pos() - self.origin) @ self.axis))

    def distance_mm(self) -> float:
        return float(to_mm(np.linalg.norm(self.sim.tip_pos() - self.target_pos())))

    def _mark_target(self, reached: bool) -> None:
        self.sim.set_target_marker(self.target_pos(), TARGET_YELLOW if reached else TARGET_WHITE)

    # ---------------------------------------------------------------- step
    def clip_action(self, action) -> np.ndarray:
        """Actions are clipped to [-0.4, 0.4]; a wrong shape or NaN is an error."""
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (ACTION_SIZE,):
            raise ValueError(f"action must have {ACTION_SIZE} values (4 cables, insertion), got shape "
                             f"{np.shape(action)}")
        if not np.isfinite(a).all():
            raise ValueError(f"action contains NaN or inf: {a}; actions must be finite numbers in "
                             f"[-{PAPER_ACTION_LIMIT}, {PAPER_ACTION_LIMIT}]")
        return np.clip(a, -PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT)

    def step(self, action) -> StepResult:
        a = self.clip_action(action)
        sim, c = self.sim, self.cfg
        lim = sim.cable_pull_max
        self.pulls = np.minimum(np.maximum(self.pulls + a[:4] * self.cable_step, -lim), lim)
        lo, hi = sim.insertion_range
        self.insertion = min(max(self.insertion + a[4] * self.insertion_step, lo), hi)
        self.prev_axial = float(a[4])
        sim.set_controls(self.pulls, self.insertion)
        instability = None
        try:
            sim.step(self.substeps)
        except InstabilityError as exc:
            instability = str(exc)
            mujoco.mj_setState(sim.model, sim.data, self._settled, mujoco.mjtState.mjSTATE_INTEGRATION)
            sim.clear_warnings()
            mujoco.mj_forward(sim.model, sim.data)
        self.steps += 1
        self.contact = sim.contact()
        force_n = float(np.sqrt(self.contact.force @ self.contact.force))
        self.peak_force = max(self.peak_force, force_n)
        tip, target = sim.tip_pos(), self.target_pos()
        delta = target - tip
        dist = float(to_mm(np.sqrt(delta @ delta)))
        ok = instability is None
        success = dist < PAPER_SUCCESS_MM and ok
        exited = self.tip_x_mm() < PAPER_EXIT_X_MM and ok
        self.sim.set_target_marker(target, TARGET_YELLOW if success else TARGET_WHITE)
        terms = {
            "reward_distance": -dist,
            "reward_success": PAPER_BONUS if success else 0.0,
            "reward_exit": -PAPER_BONUS if exited else 0.0,
            "reward_force": -c.force_penalty * force_n,
        }
        info = {
            "distance_mm": dist,
            "is_success": bool(success),
            "contact": bool(self.contact.active),
            "force_N": self.contact.force.copy(),
            "peak_force_N": self.peak_force,
            "target_index": self.target,
            "exited": bool(exited),
            "step": self.steps,
            **terms,
        }
        truncated = self.steps >= c.max_steps or not ok
        if not ok:
            info["instability"] = instability
        return StepResult(self.observation(delta), float(sum(terms.values())), bool(success or exited),
                          bool(truncated and not (success or exited)), info)

    # ---------------------------------------------------------- observation
    def observation(self, delta: np.ndarray | None = None) -> np.ndarray:
        """The observation vector (see OBS_BLOCKS); ``delta`` = target - tip if already known (m)."""
        sim = self.sim
        if delta is None:
            delta = self.target_pos() - sim.tip_pos()
        obs = np.empty(self.obs_size, np.float32)
        obs[0:3] = to_mm(delta)
        obs[3:6] = to_mm(sim.tip_vel())
        obs[6:10] = to_mm(sim.cable_lengths())
        obs[10] = self.prev_axial
        if self.cfg.force_obs:
            obs[11] = 1.0 if self.contact.active else 0.0
            obs[12:15] = self.contact.force / self.cfg.force_ref_n
        return np.clip(obs, self.obs_low, self.obs_high, out=obs)
