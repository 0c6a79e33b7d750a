"""The simulator: a loaded scene, its controls, the periodic load and contact sensing.

``Simulator("DE")`` loads the committed scene of the condition's fidelity and
sets the condition's load amplitude (SE 0, DE f0, UE1 2 f0, UE2 3 f0); ``step`` advances the
physics with cable pulls and insertion in metres, drives the square-wave
load through its actuator and checks for instability; ``contact`` reads the
endoscope-stomach contacts with ``mujoco.mj_contactForce``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from mjendo import anatomy, endoscope, scene
from mjendo.config import CURRENT_VERSION, PeriodicLoad, condition, load_gain


class InstabilityError(RuntimeError):
    """The physics diverged (NaN, exploding velocity or a MuJoCo solver warning)."""


# A generalized velocity (m/s or rad/s) that only a diverging step reaches:
# a fast cable snap spins light links at tens of rad/s, blow-ups go far past 1e3.
MAX_SPEED = 1e3


def square_wave(t: float, f0: float, half_period: float) -> float:
    """Paper's load: +f0 while (t/T) mod 2 is in [0, 1), -f0 while in [1, 2)."""
    if f0 == 0.0:
        return 0.0
    return f0 if cycle_phase(t, half_period) < 0.5 else -f0


def cycle_phase(t: float, half_period: float) -> float:
    """Where ``t`` falls in the square wave's cycle, as a share in [0, 1): the load is +f0 below 0.5."""
    return (t / half_period) % 2.0 / 2.0


def link_length(m: mujoco.MjModel, body: int) -> float:
    """Length of a scope body along its axis: its capsule's extent (0 for the carriage's point mass)."""
    geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == body and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE]
    return float(sum(2 * m.geom_size[g, 1] for g in geoms))


def oesophagus_share(start, length):
    """Share of each link (start along the pivot axis, length) that lies behind the cardia, in [0, 1].

    Works on NumPy and torch arrays alike; a point body (length 0) is behind when its start is.
    """
    return (-start / (length + 1e-9)).clip(0.0, 1.0)


@dataclass
class ContactReading:
    """Endoscope-stomach contact at one instant (world frame, newtons, metres)."""

    force: np.ndarray  # (3,) resultant force ON the endoscope
    active: bool  # contact indicator: any contact carries force
    points: np.ndarray  # (k, 3) contact positions
    forces: np.ndarray  # (k, 3) per-contact force on the endoscope


_NONE3 = np.zeros((0, 3))
_NONE3.flags.writeable = False


class Simulator:
    """One scene's model and data with named access to what the task needs."""

    def __init__(self, env: str = "DE", fidelity: str = "fast", path: Path | None = None,
                 load: PeriodicLoad | None = None, version: int = CURRENT_VERSION, stomach: Path | None = None,
                 timestep: float | None = None, contact_time_constant: float | None = None):
        self.env = condition(env)
        # The stomach's folder (None: the built-in one): its scenes, and the vertices the load pushes.
        self.stomach_dir = Path(stomach) if stomach is not None else anatomy.STOMACH_DIR
        self.path = Path(path) if path else scene.scene_path(env, fidelity, version, stomach)
        if not self.path.exists():
            raise FileNotFoundError(f"scene file {self.path} is missing; regenerate the scenes "
                                    "with `make models` (python -m mjendo.scene)")
        self.model = mujoco.MjModel.from_xml_path(str(self.path))
        if timestep is not None:  # another physics step on the same scene (TaskConfig.timestep_s)
            self.model.opt.timestep = timestep
        if contact_time_constant is not None:  # TaskConfig.contact_time_constant_s: contacts' and anchors' solref
            for solref in (self.model.geom_solref, self.model.flex_solref, self.model.eq_solref):
                solref[solref[:, 0] > 0, 0] = contact_time_constant  # (time constant, damping ratio) rows only
        self.data = mujoco.MjData(self.model)
        self._ids(self.model)
        load = load or PeriodicLoad()
        # Per-vertex force amplitude (N) of this condition's square wave, and its half period T (s).
        self.f0 = load.f0_n * self.env.load_multiplier if self.load_act >= 0 else 0.0
        # What the load actuator is driven with: f0 times the scene's calibrated gain at this load level.
        self.load_amplitude = self.f0 * self._load_gain(self.model, self.env.load_multiplier)
        self.half_period = load.half_period_s
        self._nominal_direction = np.asarray(load.direction, float) / np.linalg.norm(load.direction)
        self._along = 1.0  # share of the load along the scene's direction (its tendon): d . n
        self._across: np.ndarray | None = None  # generalized force of the rest of a tilted load's direction
        self._axes: np.ndarray | None = None
        self._scene_values = (self.load_amplitude, self.half_period, self.model.flex_stiffness.copy(),
                              self.model.flex_damping.copy(), self.model.geom_friction[:, 0].copy(),
                              self.model.flex_friction[:, 0].copy(), self.model.flex_solimp.copy())
        self.reset()

    def _ids(self, m: mujoco.MjModel) -> None:
        def aid(name):
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name)

        self.cable_act = np.array([aid(c) for c in endoscope.CABLES])
        self.insert_act = aid(endoscope.INSERTION)
        self.load_act = aid(scene.LOAD)  # -1 when the scene has no stomach
        self.cable_ten = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, c)
                                   for c in endoscope.CABLES])
        self.tip_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, endoscope.TIP_SITE)
        self.tip_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, endoscope.TIP_BODY)
        self.tip_camera = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, endoscope.TIP_CAMERA)
        self.target_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, scene.TARGET_BODY)
        self.target_mocap = m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, scene.TARGET_BODY)]
        self.insert_qpos = m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, endoscope.INSERTION)]
        self.flex = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_FLEX, scene.FLEX)
        self._vert_adr = int(m.flex_vertadr[self.flex]) if self.flex >= 0 else 0
        self._ray_vert, self._ray_normal = np.zeros(1, np.int32), np.zeros(3)  # mj_rayFlex's outputs (unused)
        # Geoms of the endoscope: every geom on a body below the carriage.
        carriage = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, endoscope.CARRIAGE)
        scope_bodies = {b for b in range(m.nbody) if self._below(m, b, carriage)}
        self.scope_geom = np.zeros(m.ngeom, bool)
        self.scope_geom[[g for g in range(m.ngeom) if m.geom_bodyid[g] in scope_bodies]] = True
        # The oesophagus carries the tube behind a compliant cardia pivot: without that support the tube's
        # weight behind the cardia would lever the pivot (it is still simulated, to be fed in).
        self.pivot = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, endoscope.PIVOT)
        self.support_body = np.array(sorted(scope_bodies), dtype=np.int64) if self.pivot >= 0 else np.zeros(0, int)
        self.support_length = np.array([link_length(m, b) for b in self.support_body])
        self.support_weight = -m.body_mass[self.support_body, None] * m.opt.gravity[None, :]
        # Where each link starts along the pivot's axis at insertion 0 (the straight tube of qpos0): the tube
        # behind the cardia lies on that axis, so how much of each link is behind depends on insertion alone
        # (both backends read it from qpos, never from positions a restart may have left stale).
        d0 = mujoco.MjData(m)
        mujoco.mj_kinematics(m, d0)
        axis0 = d0.xmat[self.pivot].reshape(3, 3)[:, 2] if self.pivot >= 0 else np.zeros(3)
        self.support_start = (d0.xpos[self.support_body] - d0.xpos[max(self.pivot, 0)]) @ axis0
        self._cable_max = m.actuator_ctrlrange[self.cable_act, 1].copy()
        self._insert_range = m.actuator_ctrlrange[self.insert_act].copy()
        self._f6 = np.zeros(6)
        self._v6 = np.zeros(6)

    @staticmethod
    def _load_gain(m: mujoco.MjModel, multiplier: float) -> float:
        i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_NUMERIC, scene.LOAD_GAINS)
        if i < 0:
            return 1.0
        return load_gain(m.numeric_data[m.numeric_adr[i]:m.numeric_adr[i] + m.numeric_size[i]], multiplier)

    @staticmethod
    def _below(m: mujoco.MjModel, body: int, root: int) -> bool:
        while body > 0:
            if body == root:
                return True
            body = m.body_parentid[body]
        return False

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def has_stomach(self) -> bool:
        return self.flex >= 0

    @property
    def cable_pull_max(self) -> np.ndarray:
        return self._cable_max

    @property
    def insertion_range(self) -> np.ndarray:
        return self._insert_range

    def tip_pos(self) -> np.ndarray:
        return self.data.site_xpos[self.tip_site].copy()

    def tip_vel(self) -> np.ndarray:
        """Linear velocity of the tip site in the world frame (m/s)."""
        v = self._v6
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, self.tip_site, v, 0)
        return v[3:].copy()

    def tip_axis(self) -> np.ndarray:
        """Unit vector along the tip (the tube's local z)."""
        return self.data.site_xmat[self.tip_site].reshape(3, 3)[:, 2].copy()

    def wall_depth(self, tilt_rad: float, range_m: float) -> np.ndarray:
        """Distance (m) from the tip camera's lens to the lumen wall along the tip axis and four rays tilted
        ``tilt_rad`` from it towards the tip frame's +x, -x, +y and -y (the bending planes); ``range_m`` where no
        wall is that near. From the lens, 4 mm behind the tip face: a tip pressing into the wall has its face in it."""
        out = np.full(5, range_m)
        if not self.has_stomach:
            return out
        frame = self.data.site_xmat[self.tip_site].reshape(3, 3)
        c, s = np.cos(tilt_rad), np.sin(tilt_rad)
        axis, x, y = frame[:, 2], frame[:, 0], frame[:, 1]
        rays = (axis, c * axis + s * x, c * axis - s * x, c * axis + s * y, c * axis - s * y)
        lens, vert, normal = self.data.cam_xpos[self.tip_camera], self._ray_vert, self._ray_normal
        for i, ray in enumerate(rays):
            # layer 0: the flex's surface faces (the lumen and the outer wall); the lumen's come first from inside
            d = mujoco.mj_rayFlex(self.model, self.data, 0, False, False, True, False, self.flex, lens, ray,
                                  vert, normal)
            if 0.0 <= d < range_m:
                out[i] = d
        return out

    def cable_lengths(self) -> np.ndarray:
        return self.data.ten_length[self.cable_ten].copy()

    def insertion(self) -> float:
        return float(self.data.qpos[self.insert_qpos])

    def vertices(self, ids=None) -> np.ndarray:
        """Current positions of stomach mesh vertices (all, or the given ids)."""
        if not self.has_stomach:
            raise ValueError(f"scene {self.env.name} has no stomach")
        adr = self._vert_adr
        if ids is None:
            return self.data.flexvert_xpos[adr:adr + self.model.flex_vertnum[self.flex]].copy()
        return self.data.flexvert_xpos[adr + np.asarray(ids)]  # fancy indexing copies

    def set_target_marker(self, pos: np.ndarray, rgba=None) -> None:
        self.data.mocap_pos[self.target_mocap] = pos
        if rgba is not None:
            self.model.site_rgba[self.target_site] = rgba

    # ------------------------------------------------------- randomization
    @property
    def load_direction(self) -> np.ndarray:
        """The scene's direction of the periodic load (unit, world frame)."""
        return self._nominal_direction.copy()

    def set_tissue(self, young_scale: float = 1.0, damping_scale: float = 1.0) -> None:
        """Scale the wall's Young's modulus and its damping from the scene's values.

        At a fixed Poisson ratio every element stiffness matrix is linear in the modulus, so scaling
        MuJoCo's precomputed ``flex_stiffness`` is the same as compiling the scene with the scaled modulus.
        """
        m = self.model
        m.flex_stiffness[:] = self._scene_values[2] * young_scale
        m.flex_damping[:] = self._scene_values[3] * damping_scale

    def set_friction(self, friction: float) -> None:
        """Sliding friction of the scope against the wall (MuJoCo takes the larger of the two sides')."""
        m = self.model
        m.geom_friction[self.scope_geom, 0] = friction
        if self.has_stomach:
            m.flex_friction[self.flex, 0] = friction

    def set_contact_solimp(self, solimp) -> None:
        """Impedance of the scope-wall contact (MuJoCo solimp: dmin, dmax, width in m, ...) in place of the
        scene's; MuJoCo mixes it with the scope's own as the scene file's does."""
        if self.has_stomach:
            self.model.flex_solimp[self.flex, :len(solimp)] = solimp

    def set_load(self, scale: float = 1.0, half_period: float | None = None, direction=None) -> None:
        """The periodic load: amplitude x ``scale`` of the condition's, half period (s), direction (world)."""
        self.load_amplitude = self._scene_values[0] * scale
        self.half_period = self._scene_values[1] if half_period is None else float(half_period)
        if direction is None or not self.has_stomach:
            self._along, self._across = 1.0, None
            return
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        n = self._nominal_direction
        self._along = float(d @ n)
        self._across = (d - self._along * n) @ self._load_axes()

    def load_phase(self) -> float:
        """The breathing cycle's phase now (share of the cycle; the clock runs in SE too, where the load is 0)."""
        return cycle_phase(self.data.time, self.half_period)

    def restore_scene_values(self) -> None:
        """Tissue, friction, contact impedance and load as the scene file has them."""
        v = self._scene_values
        self.set_tissue()
        self.model.geom_friction[:, 0] = v[4]
        self.model.flex_friction[:, 0] = v[5]
        self.model.flex_solimp[:] = v[6]
        self.set_load()

    def _load_axes(self) -> np.ndarray:
        """Generalized force of 1 N along each world axis on every forced vertex: (3, nv)."""
        if self._axes is None:
            m = self.model
            joints = scene.flex_joints(m, self.flex)
            forced = anatomy.load(self.stomach_dir).forced
            jac = scene.vertex_jacobian(m, self.flex, forced, m.jnt_qposadr[joints]).sum(0)
            self._axes = np.zeros((3, m.nv))
            self._axes[:, m.jnt_dofadr[joints]] = jac
        return self._axes

    # ---------------------------------------------------------------- control
    def set_controls(self, cable_pull: np.ndarray, insertion: float) -> None:
        """Cable pulls (m, one per cable, negative pays out) and insertion (m), clipped."""
        c = self.data.ctrl
        c[self.cable_act] = np.minimum(np.maximum(cable_pull, -self._cable_max), self._cable_max)
        c[self.insert_act] = min(max(insertion, self._insert_range[0]), self._insert_range[1])

    def support(self) -> None:
        """Hold up the part of the tube that is still in the oesophagus (behind the cardia pivot)."""
        d = self.data
        behind = oesophagus_share(self.support_start + d.qpos[self.insert_qpos], self.support_length)
        d.xfrc_applied[self.support_body, :3] = behind[:, None] * self.support_weight

    def step(self, n: int = 1) -> None:
        """Advance n physics steps, driving the periodic load; raise on divergence."""
        m, d = self.model, self.data
        loaded, supported, ctrl = self.load_act >= 0, self.support_body.size > 0, d.ctrl
        for _ in range(n):
            if loaded:
                wave = square_wave(d.time, self.load_amplitude, self.half_period)
                ctrl[self.load_act] = wave * self._along
                if self._across is not None:
                    d.qfrc_applied[:] = wave * self._across
            if supported:
                self.support()
            mujoco.mj_step(m, d)
        self.check()

    def clear_warnings(self) -> None:
        self.data.warning.number[:] = 0

    # MuJoCo resets the state itself on a NaN and only leaves one of these warnings.
    _BAD = (int(mujoco.mjtWarning.mjWARN_BADQACC), int(mujoco.mjtWarning.mjWARN_BADQVEL),
            int(mujoco.mjtWarning.mjWARN_BADQPOS))
    _BADCTRL = int(mujoco.mjtWarning.mjWARN_BADCTRL)

    def check(self) -> None:
        d = self.data
        number = d.warning.number
        if number[self._BADCTRL]:
            raise InstabilityError(f"a control was NaN or inf at t = {d.time:.3f} s (MuJoCo zeroed it, so the "
                                   "actuators stopped): check the task's action scales (cable_mm_per_unit, "
                                   "insertion_mm_per_unit) and the actions")
        bad = sum(int(number[i]) for i in self._BAD)
        speed = float(np.abs(d.qvel).max()) if d.qvel.size else 0.0
        if bad or not speed < MAX_SPEED:
            raise InstabilityError(
                f"physics diverged at t = {d.time:.3f} s (max |qvel| = {speed:.3g}, "
                f"NaN/bad-acceleration warnings = {bad}) in {self.path.name}: lower the timestep, soften the "
                "stomach (young) or reduce the load; see docs/physics.md")

    # ---------------------------------------------------------------- contact
    def contact(self, details: bool = False) -> ContactReading:
        """Resultant endoscope-stomach contact force via mj_contactForce.

        For geom-vs-flex contacts the geom (endoscope) is side 0 and the normal
        points from it into the flex; ``frame.T @ f`` is the force on side 1,
        so the force on the endoscope is its negative.
        """
        d = self.data
        n = d.ncon
        if not (n and self.has_stomach):
            return ContactReading(np.zeros(3), False, _NONE3, _NONE3)
        con = d.contact
        geom, flex = con.geom[:n], con.flex[:n]
        sel = np.flatnonzero((geom[:, 0] >= 0) & self.scope_geom[geom[:, 0]] & (flex[:, 1] == self.flex)
                             & (con.exclude[:n] == 0) & (con.efc_address[:n] >= 0))
        if not sel.size:
            return ContactReading(np.zeros(3), False, _NONE3, _NONE3)
        local = np.empty((sel.size, 3))
        f6 = self._f6
        for k, i in enumerate(sel):
            mujoco.mj_contactForce(self.model, d, int(i), f6)
            local[k] = f6[:3]
        pushing = local[:, 0] > 0.0
        if not pushing.any():
            return ContactReading(np.zeros(3), False, _NONE3, _NONE3)
        frames = con.frame[sel[pushing]].reshape(-1, 3, 3)
        # Rows of the contact frame are its axes: world = frame.T @ local, negated for side 0.
        world = -np.einsum("kji,kj->ki", frames, local[pushing])
        points = con.pos[sel[pushing]] if details else _NONE3
        return ContactReading(world.sum(0), True, points, world if details else _NONE3)
