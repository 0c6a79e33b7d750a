"""The navigation MDP, written once: state, observation, reward, termination, targets.

Both the Gymnasium env (:mod:`mjendo.envs`) and the dm_control task
(:mod:`mjendo.suite`) drive this class; neither adds task logic of its own.
Physics is SI inside; observations, rewards and reports are in millimetres,
converted only here through :mod:`mjendo.units`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import mujoco
import numpy as np

from mjendo import anatomy, mdp, targets
from mjendo.baseline import DLSController
from mjendo.config import (
    ACTION_SIZE,
    CURRENT_VERSION,
    DEPTH_RANGE_MM,
    DEPTH_TILT_DEG,
    HISTORY_STEPS,
    PAPER_ACTION_LIMIT,
    PAPER_EXIT_X_MM,
    RESIDUAL_GAIN,
    TASK_SPACE_MM_PER_UNIT,
    TASK_SPACE_SIZE,
    ConfigError,
    TaskConfig,
    default_target_list,
    substeps,
    task_config,
    wall_solimp,
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
# scope_obs: the tip position is taken from the paper frame's origin (15 mm outside the cardia), world axes.
SCOPE_BLOCKS = [("insertion", 1, "mm", (-100.0, 300.0)), ("tip_position", 3, "mm", (-1000.0, 1000.0)),
                ("tip_axis", 3, "unit vector", (-1.0, 1.0))]
TIME_BLOCKS = [("time_left", 1, "share of max_steps", (0.0, 1.0))]
PHASE_BLOCKS = [("load_phase", 2, "sin, cos of the breathing cycle's phase", (-1.0, 1.0))]
STEP_BLOCKS = [("previous_cable_actions", 4, "action units", (-PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT)),
               ("tip_step", 3, "mm", (-1000.0, 1000.0))]
DEPTH_BLOCKS = [("wall_depth", 5, "mm along the tip axis and 4 tilted rays", (0.0, DEPTH_RANGE_MM))]
NORMAL_BLOCKS = [("target_normal", 3, "unit vector into the lumen", (-1.0, 1.0))]
PLAN_BLOCKS = [("target_free_mm", 1, "mm", (0.0, 1000.0)),
               ("target_plan", targets.PLAN_SIZE - 1, "needs the wall; the map's way to it (targets.plan_vector)",
                (-1.0, 1.0))]
RESIDUAL_BLOCKS = [("baseline_action", 5, "action units", (-PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT))]
# history_obs: the observation's other blocks as they were at each of the last HISTORY_STEPS steps, newest first;
# its bounds are theirs (obs_bounds).
HISTORY_BLOCK = "previous_observations"
# The task options a policy needs its task built with, in the order their blocks follow the paper's (history_obs
# last): each adds observation blocks but task_space, which changes what an action means and adds none.
OPTION_BLOCKS = {"force_obs": FORCE_BLOCKS, "scope_obs": SCOPE_BLOCKS, "time_obs": TIME_BLOCKS,
                 "phase_obs": PHASE_BLOCKS, "step_obs": STEP_BLOCKS, "depth_obs": DEPTH_BLOCKS,
                 "normal_obs": NORMAL_BLOCKS, "plan_obs": PLAN_BLOCKS, "residual": RESIDUAL_BLOCKS, "task_space": []}
OBS_OPTIONS = (*OPTION_BLOCKS, "history_obs")
SIZE_OPTIONS = tuple(k for k in OBS_OPTIONS if k != "task_space")  # those that change the observation's size
SETTLE_S = 1.0  # the stomach settles under gravity (and load) before episodes start
# Start states are snapshots of the stomach in its periodic steady state, this
# many per load cycle (every 50 ms of a 4 s cycle): an episode starts at its
# drawn phase without a transient (docs/physics.md "Episode start").
PHASES_PER_CYCLE = 80

TARGET_WHITE = (1.0, 1.0, 1.0, 1.0)
TARGET_YELLOW = (1.0, 0.85, 0.0, 1.0)


# What an action means physically; a policy trained under other values would misbehave.
ACTION_SCALE_FIELDS = ("control_period_s", "cable_mm_per_unit", "insertion_mm_per_unit")


def obs_blocks(force_obs: bool, **options: bool) -> list[tuple]:
    """The observation's blocks (name, size, unit, bounds) with the given OBS_OPTIONS on, in their order."""
    on = {"force_obs": force_obs, **options}
    if not set(on) <= set(OBS_OPTIONS):
        raise TypeError(f"unknown observation options {sorted(set(on) - set(OBS_OPTIONS))}; valid: {OBS_OPTIONS}")
    blocks = OBS_BLOCKS + [b for name, more in OPTION_BLOCKS.items() if on.get(name) for b in more]
    if on.get("history_obs"):
        n = sum(b[1] for b in blocks)
        blocks = blocks + [(HISTORY_BLOCK, HISTORY_STEPS * n, "the blocks above, newest first", None)]
    return blocks


def action_size(cfg: TaskConfig) -> int:
    """How many values an action has: the paper's cable and insertion commands, or a tip displacement."""
    return TASK_SPACE_SIZE if cfg.task_space else ACTION_SIZE


def obs_size(force_obs: bool, **options: bool) -> int:
    return sum(b[1] for b in obs_blocks(force_obs, **options))


def obs_options(cfg: TaskConfig) -> dict[str, bool]:
    """The task's observation options (OBS_OPTIONS) by name."""
    return {k: bool(getattr(cfg, k)) for k in OBS_OPTIONS}


def obs_bounds(cfg: TaskConfig) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bound of every observation entry (the force block in units of force_ref_n)."""
    lo, hi = [], []
    for name, n, _unit, bounds in obs_blocks(**obs_options(cfg)):
        if name == HISTORY_BLOCK:
            lo, hi = lo + lo * HISTORY_STEPS, hi + hi * HISTORY_STEPS
            continue
        scale = 1.0 / cfg.force_ref_n if name == "force" else 1.0
        lo += [bounds[0] * scale] * n
        hi += [bounds[1] * scale] * n
    return np.array(lo, np.float32), np.array(hi, np.float32)


@lru_cache(maxsize=8)
def free_targets(fidelity: str, version: int = CURRENT_VERSION, stomach: Path | None = None) -> np.ndarray:
    """Where the wall would be (FE): every vertex of the settled static stomach (``stomach``: its folder)."""
    sim = Simulator("SE", fidelity, version=version, stomach=stomach)
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

    def __init__(self, cfg: TaskConfig | None = None, table: targets.TargetTable | None = None, **kw):
        self.cfg = cfg if cfg is not None else task_config(**kw)
        c = self.cfg
        self.stomach_dir = anatomy.stomach_dir(c.anatomy)
        stomach = None if c.anatomy is None else self.stomach_dir
        self.sim = Simulator(c.env, c.fidelity, version=c.version, stomach=stomach, timestep=c.timestep_s,
                             contact_time_constant=c.contact_time_constant_s)
        self.stomach = anatomy.load(self.stomach_dir)
        table = table or targets.load(c.version, targets.map_path(self.stomach_dir, c.version))
        listname = c.target_list or default_target_list(c.env, c.version)
        self.target_list = listname
        self.targets = np.array(table.listed(listname), dtype=np.int64)
        rows = table.rows(self.targets)
        # Each listed target's lumen triangle and weights, in list order (the batched backend reads them too).
        self.target_tri, self.target_bary = table.tris[rows], table.bary[rows]
        self.contact_aided = table.contact_aided(self.targets)
        # The map's class of each listed target ("free", "contact_aided"; "" where the table has none: version 0).
        self.target_classes = table.classes[rows] if table.classes is not None else np.full(len(rows), "", object)
        # sampling probabilities of the list's targets (None: uniform); a joined pool draws each list equally often
        w = table.pool_weights(listname)
        self._pool_p = None if np.ptp(w) == 0 else w / w.sum()
        self.target_p = self._pool_p
        self.cable_step = from_mm(c.cable_mm_per_unit)
        self.insertion_step = from_mm(c.insertion_mm_per_unit)
        self.substeps = substeps(c)
        self.obs_size = obs_size(**obs_options(c))
        self.obs_low, self.obs_high = obs_bounds(c)
        # The bounds of the blocks observed now (history_obs stacks copies of them behind): computed once, not per step
        n = self.obs_size // (HISTORY_STEPS + 1) if c.history_obs else self.obs_size
        self._now_low, self._now_high = self.obs_low[:n], self.obs_high[:n]
        self.control_dt = self.substeps * self.sim.model.opt.timestep
        # Paper's frame: x along the insertion axis, origin 15 mm outside the
        # cardia, so "x_EE < 15 mm" means the tip is back behind the cardia.
        self.axis = self.stomach.axis
        self.origin = self.stomach.entry - from_mm(PAPER_EXIT_X_MM) * self.axis
        self._fe_targets = None if self.sim.has_stomach else free_targets(c.fidelity, c.version, stomach)
        self._normal_stencils = self._target_normal_stencils() if c.normal_obs else None
        self.target_plans = self._target_plans(table, rows) if c.plan_obs else None
        # residual: the controller whose action the policy's corrects, and its action for the state observed last;
        # task_space: the controller that turns the policy's tip displacement into commands
        self._base = DLSController(self) if c.residual or c.task_space else None
        self.base_action = np.zeros(ACTION_SIZE)
        self._starts = self._settle()
        self._settled = self._starts[0]
        self.target = int(self.targets[0])
        self._row = 0
        self.pulls = np.zeros(4)
        self.insertion = 0.0
        self.prev_axial = 0.0
        self.prev_cables = np.zeros(4)  # the last step's commanded cable actions and tip displacement (m): step_obs
        self.tip_step = np.zeros(3)
        # history_obs: the last observation's other blocks, and the HISTORY_STEPS before it (None: no step yet)
        self._last_obs: np.ndarray | None = None
        self._history: np.ndarray | None = None
        self.steps = 0
        self.peak_force = 0.0
        self.start_index = 0
        self.contact = self.sim.contact()  # a valid reading before the first reset (dm_env asks specs first)
        # This episode's drawn tissue, load and friction (cfg.randomization), and its sensor-noise stream.
        self.episode_params: dict | None = None
        self._noise = np.random.default_rng(0)
        # The target's give under the scope this episode (m per N; Randomization.target_give_mm_per_n) and its
        # displacement now (m), added to where the wall carries it.
        self._give_m_per_n = 0.0
        self._give = np.zeros(3)

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

    @property
    def start_states(self) -> list[np.ndarray]:
        """The episode start states (MuJoCo integration states), one per load phase, in phase order."""
        return self._starts

    def _get_state(self) -> np.ndarray:
        m, d = self.sim.model, self.sim.data
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mujoco.mj_stateSize(m, spec))
        mujoco.mj_getState(m, d, state, spec)
        return state

    def reset(self, rng: np.random.Generator, phase: int | None = None) -> np.ndarray:
        """Start an episode: settled stomach, straight scope, a random target; ``phase`` picks the start state."""
        sim = self.sim
        k = phase if phase is not None else int(rng.integers(len(self._starts))) if self.cfg.randomize_phase else 0
        self.start_index = k  # which start state (load phase) this episode began from
        mujoco.mj_setState(sim.model, sim.data, self._starts[k], mujoco.mjtState.mjSTATE_INTEGRATION)
        sim.clear_warnings()  # counts belong to the previous episode
        self.pulls[:] = 0.0
        self.insertion = 0.0
        self.prev_axial = 0.0
        self.prev_cables[:] = 0.0
        self.tip_step[:] = 0.0
        self._history = None
        self.steps = 0
        self.peak_force = 0.0
        self._give_m_per_n = 0.0
        sim.set_controls(self.pulls, self.insertion)
        if self.cfg.randomization is not None:
            self._randomize(rng)
        mujoco.mj_forward(sim.model, sim.data)
        self.contact = sim.contact()
        if self._base is not None:
            self._base.reset(self)
        return self.set_target(int(rng.choice(self.targets, p=self.target_p)))

    def _randomize(self, rng: np.random.Generator) -> None:
        """Draw this episode's tissue, load and friction, and let the wall settle under them."""
        r, sim = self.cfg.randomization, self.sim
        p = r.draw(rng, sim.load_direction)
        self._noise = np.random.default_rng(int(rng.integers(2**63)))
        self.episode_params = {**p, "load_direction": [round(float(x), 6) for x in p["load_direction"]]}
        self._give_m_per_n = from_mm(p["target_give_mm_per_n"] or 0.0)
        if p["physics_step_s"] is not None:
            sim.model.opt.timestep = p["physics_step_s"]
            self.substeps = substeps(replace(self.cfg, timestep_s=p["physics_step_s"]))
        if not sim.has_stomach:
            return
        sim.set_tissue(p["young_scale"] or 1.0, p["damping_scale"] or 1.0)
        if p["friction"] is not None:
            sim.set_friction(p["friction"])
        if p["wall_compliance"] is not None:
            sim.set_contact_solimp(wall_solimp(p["wall_compliance"]))
        sim.set_load(p["load_scale"] or 1.0, p["half_period_s"], p["load_direction"])
        sim.step(int(round(r.settle_s / sim.model.opt.timestep)))

    def set_target_weights(self, weights) -> None:
        """Relative draw weight of each listed target, in list order (training's TargetSampler); None: the
        list's own draw (uniform; a joined pool: each list equally often)."""
        if weights is None:
            self.target_p = self._pool_p
            return
        w = np.asarray(weights, float)
        if w.shape != self.targets.shape or not np.all(np.isfinite(w)) or w.min() < 0 or w.sum() <= 0:
            raise ValueError(f"target weights must be {len(self.targets)} finite numbers >= 0, not all 0")
        self.target_p = None if np.all(w == w[0]) else w / w.sum()

    def set_target(self, index: int) -> np.ndarray:
        """Aim at another target of the list (its id; e.g. to replay a chosen target); returns the observation."""
        if index not in set(self.targets.tolist()):
            ids = self.targets.tolist()
            shown = ", ".join(map(str, ids[:8])) + (f", ... ({len(ids)} in all)" if len(ids) > 8 else "")
            raise ValueError(f"target {index} is not in target list {self.target_list} ({shown}); pick one of "
                             "env.task.targets")
        self.target = int(index)
        self._row = int(np.flatnonzero(self.targets == index)[0])
        self._give[:] = 0.0
        self._mark_target(False)
        mujoco.mj_kinematics(self.sim.model, self.sim.data)  # place the moved marker for the first frame
        return self.observation()

    def target_pos(self) -> np.ndarray:
        """Target position now (m): it moves with the wall in DE/UE (and gives under the scope when drawn)."""
        return self._wall_target() + self._give

    def _wall_target(self) -> np.ndarray:
        r = self._row
        corners = self._fe_targets[self.target_tri[r]] if self._fe_targets is not None \
            else self.sim.vertices(self.target_tri[r])
        return self.target_bary[r] @ corners

    def _target_normal_stencils(self) -> list[tuple[np.ndarray, list[np.ndarray]]]:
        """Per listed target: the lumen vertices around its triangle's corners and, per corner, the lumen faces
        at it (in those vertices' indices): what its surface normal is interpolated from."""
        faces = targets.lumen_triangles(self.stomach)
        stencils = []
        for tri in self.target_tri:
            around = [faces[np.any(faces == v, axis=1)] for v in tri]
            ids, local = np.unique(np.concatenate(around), return_inverse=True)
            stencils.append((ids, np.split(local.reshape(-1, 3), np.cumsum([len(f) for f in around])[:-1])))
        return stencils

    @staticmethod
    def _target_plans(table: targets.TargetTable, rows: np.ndarray) -> np.ndarray:
        """Each listed target's plan from the stomach's map (plan_obs), in list order."""
        if table.free_mm is None:
            raise ConfigError("plan_obs needs a target map with each point's free-space distance, as `python -m "
                              "mjendo.targets map` measures it (task version 1 or later; version 0's vertex targets "
                              "have none): measure the stomach's map or drop plan_obs")
        return np.array([targets.plan_vector(table.free_mm[r], int(table.demos[r])) for r in rows])

    def target_normal(self) -> np.ndarray:
        """The lumen surface's unit normal at the target now, into the lumen: its corners' area-weighted vertex
        normals over the lumen's faces (which the wall's boundary orients out of the tissue), blended by the
        target's barycentric weights, so it turns smoothly as the wall moves and across triangles."""
        ids, corner_faces = self._normal_stencils[self._row]
        p = self._fe_targets[ids] if self._fe_targets is not None else self.sim.vertices(ids)
        normal = np.zeros(3)
        for weight, f in zip(self.target_bary[self._row], corner_faces, strict=True):
            n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]).sum(axis=0)
            normal += weight * n / np.linalg.norm(n)
        return normal / np.linalg.norm(normal)

    def push_near_target(self, contact, sigma_mm: float) -> np.ndarray:
        """The scope's push on the wall (N) from a detailed contact reading, each contact weighted by
        exp(-d^2 / 2 sigma^2) of its distance d to where the wall carries the target: what the target give
        scales, and what ``mjendo.fidelity give`` fits the give to."""
        if not contact.active:
            return np.zeros(3)
        d2 = np.sum((np.asarray(contact.points) - self._wall_target()) ** 2, axis=1)
        return np.exp(-d2 / (2 * from_mm(sigma_mm) ** 2)) @ -np.asarray(contact.forces)  # readings: force on the scope

    def _update_give(self) -> None:
        """Displace the target along the scope's push on the wall nearby (Randomization.target_give_mm_per_n):
        the dent a reduced-order wall cannot make, quasi-static."""
        self._give = self._give_m_per_n * self.push_near_target(self.contact,
                                                                self.cfg.randomization.target_give_sigma_mm)

    def list_positions(self) -> np.ndarray:
        """Positions (m) of every target of the list now, in list order."""
        verts = self._fe_targets if self._fe_targets is not None else self.sim.vertices()
        return np.einsum("nk,nkd->nd", self.target_bary, verts[self.target_tri])

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
        n = action_size(self.cfg)
        if a.shape != (n,):
            what = "the tip displacement's x, y, z (task_space)" if self.cfg.task_space else "4 cables, insertion"
            raise ValueError(f"action must have {n} values ({what}), got shape {np.shape(action)}")
        if not np.isfinite(a).all():
            raise ValueError(f"action contains NaN or inf: {a}; actions must be finite numbers in "
                             f"[-{PAPER_ACTION_LIMIT}, {PAPER_ACTION_LIMIT}]")
        return np.clip(a, -PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT)

    def step(self, action) -> StepResult:
        a = self.clip_action(action)
        if self.cfg.task_space:  # the controller moves the tip where the policy asks
            a = self._base.toward(self, from_mm(a * TASK_SPACE_MM_PER_UNIT))
        elif self._base is not None:  # the policy corrects the baseline's action for the state it observed
            a = np.clip(self.base_action + RESIDUAL_GAIN * a, -PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT)
        sim = self.sim
        done = a * self._actuation_gains()
        lim = sim.cable_pull_max
        self.pulls = np.minimum(np.maximum(self.pulls + done[:4] * self.cable_step, -lim), lim)
        lo, hi = sim.insertion_range
        self.insertion = min(max(self.insertion + done[4] * self.insertion_step, lo), hi)
        self.prev_axial = float(a[4])
        self.prev_cables = a[:4].copy()
        if self.cfg.history_obs:  # the observation this action answered becomes the newest past one
            self._history = np.concatenate([self._last_obs[None], self._past()[:-1]])
        tip_before = sim.tip_pos().copy() if self.cfg.step_obs else None
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
        if tip_before is not None:
            self.tip_step = sim.tip_pos() - tip_before
        self.contact = sim.contact(details=bool(self._give_m_per_n))
        if self._give_m_per_n:
            self._update_give()
        ok = instability is None
        target = self.target_pos()
        out = mdp.outcome(self.cfg, sim.tip_pos()[None], target[None], self.origin, self.axis,
                          self.contact.force[None], np.array([self.steps]), np.array([ok]))
        out = {k: v[0] for k, v in out.items()}
        self.peak_force = max(self.peak_force, float(out["force_n"]))
        success = bool(out["is_success"])
        self.sim.set_target_marker(target, TARGET_YELLOW if success else TARGET_WHITE)
        info = {
            "distance_mm": float(out["distance_mm"]),
            "is_success": success,
            "contact": bool(self.contact.active),
            "force_N": self.contact.force.copy(),
            "peak_force_N": self.peak_force,
            "target_index": self.target,
            "anatomy": self.cfg.anatomy,
            "exited": bool(out["exited"]),
            "step": self.steps,
            **{k: float(out[k]) for k in mdp.REWARD_TERMS},
        }
        if not ok:
            info["instability"] = instability
        return StepResult(self.observation(out["delta"]), float(out["reward"]), bool(out["terminated"]),
                          bool(out["truncated"]), info)

    def _actuation_gains(self) -> np.ndarray | float:
        """Executed over commanded increment, per channel: 1 unless the randomization draws actuation error."""
        r = self.cfg.randomization
        if r is None or r.actuation_noise == 0:
            return 1.0
        return 1.0 + self._noise.normal(0.0, r.actuation_noise, ACTION_SIZE)

    # ---------------------------------------------------------- observation
    def observation(self, delta: np.ndarray | None = None) -> np.ndarray:
        """The observation vector (see OBS_BLOCKS); ``delta`` = target - tip if already known (m)."""
        sim = self.sim
        if delta is None:
            delta = self.target_pos() - sim.tip_pos()
        scope = (np.array([sim.insertion()]), (sim.tip_pos() - self.origin)[None], sim.tip_axis()[None]) \
            if self.cfg.scope_obs else None
        force = self.contact.force
        r = self.cfg.randomization
        if r is not None:  # sensor noise: the tracker's on the target vector, the tip sensor's on the force
            delta = delta + self._noise.normal(0.0, from_mm(r.target_noise_mm), 3)
            force = force + self._noise.normal(0.0, r.force_noise_n, 3)
        left = np.array([1.0 - self.steps / self.cfg.max_steps]) if self.cfg.time_obs else None
        phase = np.array([sim.load_phase()]) if self.cfg.phase_obs else None
        step = (self.prev_cables[None], self.tip_step[None]) if self.cfg.step_obs else None
        depth = sim.wall_depth(math.radians(DEPTH_TILT_DEG), from_mm(DEPTH_RANGE_MM))[None] \
            if self.cfg.depth_obs else None
        normal = self.target_normal()[None] if self.cfg.normal_obs else None
        plan = self.target_plans[self._row][None] if self.cfg.plan_obs else None
        if self.cfg.residual:
            self.base_action = self._base.act(None, self)
        base = self.base_action[None] if self.cfg.residual else None
        obs = mdp.observe(np, self.cfg, delta[None], sim.tip_vel()[None], sim.cable_lengths()[None],
                          np.array([self.prev_axial]), np.array([float(self.contact.active)]),
                          force[None], self._now_low, self._now_high, scope, left, phase, step, depth, normal,
                          plan, base)[0]
        if not self.cfg.history_obs:
            return obs
        self._last_obs = obs
        return np.concatenate([obs, self._past().ravel()])

    def _past(self) -> np.ndarray:
        """The HISTORY_STEPS observations before the last one; before an episode's first step, the first
        repeated (the scope has stood there until now)."""
        return self._history if self._history is not None else np.tile(self._last_obs, (HISTORY_STEPS, 1))
