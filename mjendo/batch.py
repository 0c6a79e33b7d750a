"""N worlds of the navigation task on MuJoCo Warp: the NavigationTask MDP, batched (GPU, or Warp's CPU device).

Physics runs in MuJoCo Warp (``mujoco_warp.step`` over all worlds); the task
logic (actions, the periodic load with a per-world phase, observations with
the contact indicator and resultant contact force, rewards, termination,
targets that move with the wall, auto-reset) runs in torch on the same
device, on zero-copy views of Warp's arrays: no Python loop over worlds.
Every constant of the MDP comes from the CPU :class:`~mjendo.task.NavigationTask`
of the same config (start states, target lists, frame, scales), so both
backends define one task.

Needs the optional extra ``mjendo[warp]`` (``mujoco-warp``, ``warp-lang``).
"""

from __future__ import annotations

import copy
import os
import sys
import warnings
from dataclasses import dataclass

import mujoco
import numpy as np

from mjendo import mdp, warp_patch
from mjendo.config import (
    ACTION_SIZE,
    PAPER_ACTION_LIMIT,
    ConfigError,
    TaskConfig,
    task_config,
)
from mjendo.scene import solver_id
from mjendo.sim import MAX_SPEED, oesophagus_share
from mjendo.task import OBS_OPTIONS, NavigationTask


def _require():
    try:
        import mujoco_warp
        import torch
        import warp
    except ImportError as exc:
        raise ConfigError("the batched backend needs MuJoCo Warp: install it with `pip install 'mjendo[warp]'` "
                          f"({exc})") from exc
    init_quietly(warp)
    warp_patch.apply()
    return warp, mujoco_warp, torch


_WARP_READY = False

def init_quietly(wp) -> None:
    """Initialise Warp without its banner (on a machine without a GPU it also prints a CUDA warning from C)."""
    global _WARP_READY
    if _WARP_READY:
        return
    _WARP_READY = True
    wp.config.quiet = True
    sys.stdout.flush()
    saved = os.dup(1), os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        wp.init()
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


def _signed(c: int) -> int:
    return c - (1 << 64) if c >= 1 << 63 else c


_GOLD, _MIX1, _MIX2 = _signed(0x9E3779B97F4A7C15), _signed(0xBF58476D1CE4E5B9), _signed(0x94D049BB133111EB)


def uniform(seed, counter, stream: int):
    """Counter-based uniform numbers in [0, 1): one independent stream per (world seed, episode, use).

    splitmix64 on int64 tensors (multiplication wraps, shifts are masked to be logical), so every world
    draws its own reproducible numbers whatever the other worlds do.
    """
    x = seed * _GOLD + counter * _MIX1 + stream
    x = (x ^ ((x >> 30) & ((1 << 34) - 1))) * _MIX1
    x = (x ^ ((x >> 27) & ((1 << 37) - 1))) * _MIX2
    x = x ^ ((x >> 31) & ((1 << 33) - 1))
    return ((x >> 11) & ((1 << 53) - 1)).double() / float(1 << 53)


# Contact and constraint buffers per world. With 64 contacts the fast stomach lost its deepest contacts in a hard
# press (Warp 0.08 N against MuJoCo's 7.4 N for the same state; tests/test_batch.py); 256 is MuJoCo Warp's own
# default for flex scenes and kept every contact in every press measured.
NCONMAX, NJMAX = 256, 1024


def with_solver(m: mujoco.MjModel, solver: str | None) -> mujoco.MjModel:
    """A copy for MuJoCo Warp, optionally solving its constraints with another solver (the same physics).

    On a GPU a step waits for its slowest world: CG in the full stomach stops at its cap on about 12 % of
    contact world-steps, Newton converges in at most 7 iterations but factors an 822-dof Hessian per world;
    which is faster there is for ``python -m mjendo.bench --only batched --batched-solvers`` to say.
    Warp picks the Jacobian's storage itself (it refuses a dense one beyond 60 dofs): storage is not physics.
    """
    out = copy.copy(m)
    out.opt.jacobian = mujoco.mjtJacobian.mjJAC_AUTO
    if solver is not None:
        out.opt.solver = solver_id(solver)
    return out


@dataclass
class BatchStep:
    """One step of all worlds (tensors on the batch's device, leading dimension N)."""

    obs: object
    reward: object
    terminated: object
    truncated: object
    info: dict


class BatchedNavigation:
    """``n_worlds`` copies of one task condition, stepped together; each world resets itself when it ends.

    ``solver`` ("CG" or "Newton") overrides the scene's constraint solver for the worlds (see :func:`with_solver`);
    ``nconmax``/``njmax`` size the contact and constraint buffers per world.
    """

    render_mode = None  # no rendering here: record with the CPU env (mjendo.viewer)

    def __init__(self, n_worlds: int, cfg: TaskConfig | None = None, device: str | None = None, seed: int = 0,
                 nconmax: int | None = None, njmax: int | None = None, solver: str | None = None, **task):
        wp, mjw, torch = _require()
        if isinstance(n_worlds, bool) or not isinstance(n_worlds, int) or n_worlds < 1:
            raise ConfigError(f"n_worlds must be a whole number >= 1, not {n_worlds!r}")
        self.cfg = cfg if cfg is not None else task_config(**task)
        if self.cfg.randomization is not None:
            raise ConfigError("randomization (per-episode tissue, load and noise) is not available in the batched "
                              "backend: train such a policy with --backend cpu")
        if any(getattr(self.cfg, k) for k in OBS_OPTIONS if k != "force_obs"):
            raise ConfigError("scope_obs, time_obs, phase_obs, step_obs, depth_obs, normal_obs, plan_obs, residual, "
                              "task_space and history_obs are not available in the batched backend: train such a "
                              "policy with --backend cpu")
        self.core = NavigationTask(self.cfg)  # the MDP's constants: start states, targets, frame, scales
        core, m = self.core, self.core.sim.model
        self.wp_device = device or ("cuda:0" if wp.is_cuda_available() else "cpu")
        self.device = torch.device(str(self.wp_device))
        self.n = n_worlds
        with wp.ScopedDevice(self.wp_device):
            solved = with_solver(m, solver)
            self.mjm = solved  # the MuJoCo model Warp holds (its Jacobian storage may differ from the CPU's)
            self.mw = mjw.put_model(solved)
            if hasattr(self.mw.opt, "warn_overflow"):
                self.mw.opt.warn_overflow = 0  # Warp would print per world-step; _check_step counts instead
            self.d = mjw.make_data(solved, nworld=n_worlds, nconmax=nconmax or NCONMAX, njmax=njmax or NJMAX)
        # Warp's per-world flags: lost contacts or constraint rows (buffers too small), a solve stopped at the
        # iteration cap (unconverged), a line search stopped at its own cap (not counted).
        iterations = mjw.OverflowType.ITERATIONS
        self._overflow_bits = int(mjw.OverflowType.ALL & ~(iterations | mjw.OverflowType.LS_ITERATIONS))
        self._solver_bits = int(iterations)
        self.overflows = 0  # world control steps that lost contacts or constraint rows
        # World control steps in which a constraint solve stopped at the iteration cap, of world_steps: the
        # scene's solver decides this (Newton in the fast stomach: none seen so far; docs/backends.md).
        self.solver_capped = self.world_steps = 0
        self._mjw, self._wp, self._torch = mjw, wp, torch
        t = self._t
        self._overflow_flags = self._t(self.d.overflow)  # zero-copy view, made once: step() reads it every step
        d, s = self.d, core.sim
        self.qpos, self.qvel, self.ctrl = t(d.qpos), t(d.qvel), t(d.ctrl)
        self.time, self.warmstart = t(d.time), t(d.qacc_warmstart)
        self.act = t(d.act) if m.na else None
        # Index tensors of what the task reads.
        self.cable_act = torch.as_tensor(s.cable_act, device=self.device)
        self.cable_ten = torch.as_tensor(s.cable_ten, device=self.device)
        self.cable_max = torch.as_tensor(s.cable_pull_max, device=self.device, dtype=torch.float64)
        self.ins_lo, self.ins_hi = (float(x) for x in s.insertion_range)
        self.targets = torch.as_tensor(core.targets, device=self.device)
        self.target_tri = torch.as_tensor(core.target_tri, device=self.device)
        self.target_bary = torch.as_tensor(core.target_bary, device=self.device, dtype=torch.float64)
        # The oesophagus' support of the tube behind the cardia pivot (Simulator.support), per world.
        self.support_body = torch.as_tensor(s.support_body, device=self.device)
        self.support_length = torch.as_tensor(s.support_length, device=self.device, dtype=torch.float64)
        self.support_weight = torch.as_tensor(s.support_weight, device=self.device, dtype=torch.float64)
        self.support_start = torch.as_tensor(s.support_start, device=self.device, dtype=torch.float64)
        self.xfrc = t(d.xfrc_applied) if len(s.support_body) else None
        self.axis = torch.as_tensor(core.axis, device=self.device, dtype=torch.float64)
        self.origin = torch.as_tensor(core.origin, device=self.device, dtype=torch.float64)
        self.obs_low = torch.as_tensor(core.obs_low, device=self.device)
        self.obs_high = torch.as_tensor(core.obs_high, device=self.device)
        scope = np.flatnonzero(s.scope_geom)
        self.scope_geom = torch.zeros(m.ngeom, dtype=torch.bool, device=self.device)
        self.scope_geom[torch.as_tensor(scope, device=self.device)] = True
        self.root = int(m.body_rootid[s.tip_body])
        self._starts = self._start_states()
        self._fe_targets = (torch.as_tensor(core._fe_targets, device=self.device, dtype=torch.float64)
                            if core._fe_targets is not None else None)
        # Per-world task state.
        f64 = {"device": self.device, "dtype": torch.float64}
        self.pulls = torch.zeros(n_worlds, 4, **f64)
        self.insertion = torch.zeros(n_worlds, **f64)
        self.prev_axial = torch.zeros(n_worlds, **f64)
        self.steps = torch.zeros(n_worlds, dtype=torch.int64, device=self.device)
        self.target = torch.zeros(n_worlds, dtype=torch.int64, device=self.device)
        self.target_row = torch.zeros(n_worlds, dtype=torch.int64, device=self.device)  # its row in the list
        self.phase = torch.zeros(n_worlds, dtype=torch.int64, device=self.device)  # start snapshot drawn
        self.episode_return = torch.zeros(n_worlds, **f64)
        self.peak_force = torch.zeros(n_worlds, **f64)
        self.world_seed = seed * 1_000_003 + torch.arange(n_worlds, device=self.device, dtype=torch.int64)
        self.episodes = torch.zeros(n_worlds, dtype=torch.int64, device=self.device)
        self._contact_ids = wp.array(np.arange(d.naconmax, dtype=np.int32), dtype=int, device=self.wp_device)
        self._contact_out = wp.zeros(d.naconmax, dtype=wp.spatial_vector, device=self.wp_device)
        self.force = torch.zeros(n_worlds, 3, **f64)
        # Each world's time in float64, advanced like MuJoCo's on the CPU: Warp's float32 time can land on the
        # other side of a load switch (t = 2T) and flip the square wave for a step.
        self.clock = torch.zeros(n_worlds, **f64)
        self.dt = float(m.opt.timestep)
        self.contact = torch.zeros(n_worlds, dtype=torch.bool, device=self.device)

    # ------------------------------------------------------------------ plumbing
    def _t(self, arr):
        return self._wp.to_torch(arr)

    def _start_states(self) -> dict:
        """The CPU task's start snapshots (one per load phase) as tensors, with what its first observation reads.

        qpos, qvel, act, time, warm start to restart a world; tip position and velocity, cable lengths, contact
        and force, and every listed target's position, computed by the CPU task's reset (``mj_forward``) once per
        snapshot, so a restarting world needs no forward pass of its own (it cost as much as a physics step).
        """
        torch, core = self._torch, self.core
        sim = core.sim
        m, data = sim.model, sim.data
        fields: dict[str, list] = {k: [] for k in ("qpos", "qvel", "act", "time", "warmstart", "tip", "tip_vel",
                                                   "cable", "contact", "force", "targets")}
        for state in core._starts:
            mujoco.mj_setState(m, data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
            sim.set_controls(np.zeros(4), 0.0)
            mujoco.mj_forward(m, data)
            reading = sim.contact()
            targets = core.list_positions()
            for k, v in (("qpos", data.qpos), ("qvel", data.qvel), ("act", data.act), ("time", [data.time]),
                         ("warmstart", data.qacc_warmstart), ("tip", sim.tip_pos()), ("tip_vel", sim.tip_vel()),
                         ("cable", sim.cable_lengths()), ("contact", [float(reading.active)]),
                         ("force", reading.force), ("targets", targets)):
                fields[k].append(np.array(v, dtype=np.float64))
        return {k: torch.as_tensor(np.stack(v), device=self.device) for k, v in fields.items()}

    # ------------------------------------------------------------------ episodes
    def reset(self, mask=None):
        """Start new episodes in the worlds of ``mask`` (all by default): a drawn load phase and target.

        Returns every world's observation. Warp's derived data (positions, contacts) of a restarted world stay
        those of before its restart until its next step, which recomputes them first.
        """
        torch = self._torch
        if mask is None:
            mask = torch.ones(self.n, dtype=torch.bool, device=self.device)
        idx = torch.nonzero(mask).squeeze(1)
        obs = self.observation() if idx.numel() < self.n else torch.empty(self.n, self.core.obs_size,
                                                                           device=self.device)
        if idx.numel():
            obs[idx] = self._restart(idx)
        return obs

    def _restart(self, idx):
        """Restart the worlds ``idx`` from drawn start snapshots; their first observations, from the tables."""
        torch = self._torch
        seed, ep = self.world_seed[idx], self.episodes[idx]
        n_starts = self._starts["qpos"].shape[0]
        phase = (uniform(seed, ep, 1) * n_starts).long().clamp(max=n_starts - 1) if self.cfg.randomize_phase \
            else torch.zeros_like(idx)
        st = self._starts
        for name in ("qpos", "qvel", "warmstart"):
            getattr(self, name)[idx] = st[name][phase].to(getattr(self, name).dtype)
        self.clock[idx] = st["time"][phase].squeeze(1)
        self.time[idx] = self.clock[idx].to(self.time.dtype)
        if self.act is not None:
            self.act[idx] = st["act"][phase].to(self.act.dtype)
        pick = (uniform(seed, ep, 2) * len(self.targets)).long().clamp(max=len(self.targets) - 1)
        self.target[idx] = self.targets[pick]
        self.target_row[idx] = pick
        self.phase[idx] = phase
        self.pulls[idx] = 0.0
        self.insertion[idx] = 0.0
        self.prev_axial[idx] = 0.0
        self.steps[idx] = 0
        self.episode_return[idx] = 0.0
        self.peak_force[idx] = 0.0
        self.episodes[idx] += 1
        self.contact[idx] = st["contact"][phase, 0] > 0
        self.force[idx] = st["force"][phase]
        self._write_controls()
        return self._observe(st["targets"][phase, pick] - st["tip"][phase], st["tip_vel"][phase], st["cable"][phase],
                             self.prev_axial[idx], self.contact[idx], self.force[idx])

    # ------------------------------------------------------------------ physics
    def _write_controls(self) -> None:
        torch, s = self._torch, self.core.sim
        ctrl = self.ctrl
        ctrl[:, self.cable_act] = torch.clamp(self.pulls, -self.cable_max, self.cable_max).to(ctrl.dtype)
        ctrl[:, s.insert_act] = torch.clamp(self.insertion, self.ins_lo, self.ins_hi).to(ctrl.dtype)
        self._write_load()

    def _write_load(self) -> None:
        """The paper's square wave at every world's own time (+f0 in [0, T), -f0 in [T, 2T))."""
        s = self.core.sim
        if s.load_act < 0:
            return
        up = self._torch.remainder(self.clock / s.half_period, 2.0) < 1.0
        self.ctrl[:, s.load_act] = self._torch.where(up, s.load_amplitude, -s.load_amplitude).to(self.ctrl.dtype)

    def _write_support(self) -> None:
        """The oesophagus holds up the tube behind the cardia pivot in every world (as Simulator.support)."""
        s = self.core.sim
        share = oesophagus_share(self.support_start + self.qpos[:, s.insert_qpos, None].double(), self.support_length)
        self.xfrc[:, self.support_body, :3] = (share[..., None] * self.support_weight).to(self.xfrc.dtype)

    def _physics(self) -> None:
        for _ in range(self.core.substeps):
            self._physics_step()

    def _physics_step(self) -> None:
        """One physics step of every world with the load at each world's time (no task logic)."""
        self._write_load()
        if self.xfrc is not None:
            self._write_support()
        self._mjw.step(self.mw, self.d)
        self.clock += self.dt

    def _check_step(self) -> None:
        """Count the worlds whose solver stopped at its cap; warn (once) when a world lost contacts to full buffers."""
        flags = self._overflow_flags
        lost, capped, flagged = self._torch.stack([((flags & self._overflow_bits) != 0).sum(),
                                                   ((flags & self._solver_bits) != 0).sum(),
                                                   (flags != 0).sum()]).tolist()
        self.solver_capped += capped
        self.world_steps += self.n
        if lost:
            if not self.overflows:
                warnings.warn(f"{lost} of {self.n} worlds ran out of contact/constraint buffers (nconmax="
                              f"{self.d.naconmax // self.n}, njmax={self.d.njmax}) and lost contacts: pass larger "
                              "nconmax/njmax to BatchedNavigation", RuntimeWarning, stacklevel=3)
            self.overflows += lost
        if flagged:
            flags.zero_()

    @property
    def capped_fraction(self) -> float:
        """Share of world-steps whose constraint solve stopped at the iteration cap, unconverged."""
        return self.solver_capped / max(1, self.world_steps)

    def _read_contact(self) -> None:
        """Resultant endoscope-stomach contact force per world, as mjendo.sim.Simulator.contact computes it."""
        torch, s = self._torch, self.core.sim
        if not s.has_stomach:  # FE: the scope touches only the hiatus ring, which is not the wall
            self.force.zero_()
            self.contact.zero_()
            return
        self._contact_out.zero_()
        self._mjw.contact_force(self.mw, self.d, self._contact_ids, False, self._contact_out)
        local = self._t(self._contact_out)[:, :3].double()
        c = self.d.contact
        n = int(self.d.nacon.numpy()[0])
        geom, flex = self._t(c.geom)[:n], self._t(c.flex)[:n]
        valid = (geom[:, 0] >= 0) & (flex[:, 1] == s.flex) & (self._t(c.efc_address)[:n, 0] >= 0)
        valid &= self.scope_geom[geom[:, 0].clamp(min=0).long()]
        valid &= local[:n, 0] > 0.0  # pushing, as the CPU reading keeps
        frame = self._t(c.frame)[:n].double()
        world = -torch.einsum("kji,kj->ki", frame, local[:n])  # the force on the scope (geom side 0)
        world = world * valid[:, None]
        worldid = self._t(c.worldid)[:n].long()
        self.force = torch.zeros(self.n, 3, dtype=torch.float64, device=self.device).index_add_(0, worldid, world)
        self.contact = torch.zeros(self.n, dtype=torch.int64, device=self.device).index_add_(
            0, worldid, valid.long()) > 0

    # ------------------------------------------------------------------ task
    def tip_pos(self):
        return self._t(self.d.site_xpos)[:, self.core.sim.tip_site].double()

    def tip_vel(self):
        """Linear velocity of the tip site (world frame): com-based body velocity moved to the site."""
        torch = self._torch
        b = self.core.sim.tip_body
        cvel = self._t(self.d.cvel)[:, b].double()
        com = self._t(self.d.subtree_com)[:, self.root].double()
        return cvel[:, 3:] + torch.cross(cvel[:, :3], self.tip_pos() - com, dim=1)

    def target_pos(self):
        tri, bary = self.target_tri[self.target_row], self.target_bary[self.target_row]
        if self._fe_targets is not None:
            corners = self._fe_targets[tri]
        else:
            verts = self._t(self.d.flexvert_xpos).double()
            corners = verts[self._torch.arange(self.n, device=self.device)[:, None], self.core.sim._vert_adr + tri]
        return (bary[..., None] * corners).sum(1)

    def observation(self, delta=None):
        """Every world's observation after its last step (``delta`` = target - tip if already known, m)."""
        if delta is None:
            delta = self.target_pos() - self.tip_pos()
        cable = self._t(self.d.ten_length)[:, self.cable_ten].double()
        return self._observe(delta, self.tip_vel(), cable, self.prev_axial, self.contact, self.force)

    def _observe(self, delta, tip_vel, cable, prev_axial, contact, force):
        """The task's observation rows (mjendo.mdp.observe) from their parts (SI units in, millimetres out)."""
        return mdp.observe(self._torch, self.cfg, delta, tip_vel, cable, prev_axial, contact.double(), force,
                           self.obs_low, self.obs_high)

    def step(self, action) -> BatchStep:
        """Apply (N, 5) actions, advance every world one control step, reset the worlds that ended.

        ``info["final_obs"]`` holds the last observation of the worlds that ended (the returned ``obs``
        of those worlds is already the first of their next episode), as vectorised envs report it.
        """
        torch, c = self._torch, self.cfg
        a = torch.as_tensor(action, device=self.device, dtype=torch.float64).reshape(self.n, ACTION_SIZE)
        if not torch.isfinite(a).all():
            raise ValueError("actions contain NaN or inf; actions must be finite numbers in "
                             f"[-{PAPER_ACTION_LIMIT}, {PAPER_ACTION_LIMIT}]")
        a = a.clamp(-PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT)
        self.pulls = torch.clamp(self.pulls + a[:, :4] * self.core.cable_step, -self.cable_max, self.cable_max)
        self.insertion = torch.clamp(self.insertion + a[:, 4] * self.core.insertion_step, self.ins_lo, self.ins_hi)
        self.prev_axial = a[:, 4].clone()
        self._write_controls()
        self._physics()
        self._check_step()
        self.steps += 1
        qvel = self.qvel.double()
        unstable = ~torch.isfinite(qvel).all(dim=1) | (qvel.abs().max(dim=1).values >= MAX_SPEED)
        self._read_contact()
        out = mdp.outcome(c, self.tip_pos(), self.target_pos(), self.origin, self.axis, self.force, self.steps,
                          ~unstable)
        self.peak_force = torch.maximum(self.peak_force, out["force_n"])
        reward, terminated, truncated, delta = out["reward"], out["terminated"], out["truncated"], out["delta"]
        obs = self.observation(delta)
        self.episode_return += reward
        done = terminated | truncated
        info = {"distance_mm": out["distance_mm"], "is_success": out["is_success"], "exited": out["exited"],
                "contact": self.contact.clone(), "force_N": self.force.clone(), "peak_force_N": self.peak_force.clone(),
                "target_index": self.target.clone(), "step": self.steps.clone(), "unstable": unstable,
                **{k: out[k] for k in mdp.REWARD_TERMS},
                "episode_return": self.episode_return.clone(), "episode_length": self.steps.clone(),
                "final_obs": obs.clone()}
        if done.any():
            idx = torch.nonzero(done).squeeze(1)
            obs[idx] = self._restart(idx)
        return BatchStep(obs, reward, terminated, truncated, info)



def vec_env(n_worlds: int, cfg: TaskConfig, device: str | None = None, seed: int = 0):
    """A Stable-Baselines3 ``VecEnv`` over a :class:`BatchedNavigation` (numpy in and out, auto-reset)."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    class WarpVecEnv(VecEnv):
        """SB3's view of the batch: every world is one environment; infos carry what Monitor would log."""

        def __init__(self):
            self.batch = BatchedNavigation(n_worlds, cfg, device=device, seed=seed)
            b = self.batch
            space = gym.spaces.Box(b.core.obs_low, b.core.obs_high, dtype=np.float32)
            action = gym.spaces.Box(-PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT, (ACTION_SIZE,), np.float32)
            super().__init__(n_worlds, space, action)
            self._actions = None

        def reset(self):
            return self.batch.reset().cpu().numpy()

        def step_async(self, actions):
            self._actions = actions

        def step_wait(self):
            r = self.batch.step(self._actions)
            done = (r.terminated | r.truncated).cpu().numpy()
            info = {k: v.cpu().numpy() for k, v in r.info.items()}
            infos = [{} for _ in range(self.num_envs)]
            for i in np.flatnonzero(done):
                infos[i] = {"terminal_observation": info["final_obs"][i], "is_success": bool(info["is_success"][i]),
                            "distance_mm": float(info["distance_mm"][i]),
                            "TimeLimit.truncated": bool(r.truncated[i]) and not bool(r.terminated[i]),
                            "episode": {"r": float(info["episode_return"][i]), "l": int(info["episode_length"][i]),
                                        "t": 0.0}}
            return r.obs.cpu().numpy(), r.reward.cpu().numpy().astype(np.float32), done, infos

        def close(self):
            pass

        def get_attr(self, attr_name, indices=None):
            return [getattr(self.batch, attr_name)] * len(self._get_indices(indices))

        def set_attr(self, attr_name, value, indices=None):
            setattr(self.batch, attr_name, value)

        def env_method(self, method_name, *args, indices=None, **kwargs):
            return [getattr(self.batch, method_name)(*args, **kwargs)] * len(self._get_indices(indices))

        def env_is_wrapped(self, wrapper_class, indices=None):
            return [False] * len(self._get_indices(indices))

    return WarpVecEnv()


def success_rate(policy_dir, cfg: TaskConfig, n_worlds: int, episodes: int, device: str | None = None,
                 seed: int = 0) -> dict:
    """Deterministic trials of a trained policy over many worlds: the first ``episodes`` episodes to end.

    The policy folder is read as the CPU tools read it (:mod:`mjendo.artifacts`): same normalisation, same
    checks; its actions are computed for all worlds at once.
    """

    from mjendo.policies import PPOController

    ctrl = PPOController.from_folder(policy_dir)
    batch = BatchedNavigation(n_worlds, cfg, device=device, seed=seed)
    ctrl.check(batch.core)
    obs = batch.reset()
    successes, errors = [], []
    while len(successes) < episodes:
        r = batch.step(ctrl.act(obs.cpu().numpy(), batch.core))
        done = (r.terminated | r.truncated).cpu().numpy()
        successes += r.info["is_success"].cpu().numpy()[done].tolist()
        errors += r.info["distance_mm"].cpu().numpy()[done].tolist()
        obs = r.obs
    return {"episodes": episodes, "success_rate": float(np.mean(successes[:episodes])),
            "mean_final_mm": float(np.mean(errors[:episodes])), "device": batch.wp_device}
