"""Every physical number of mjendo, in one place, with where it comes from.

"paper" means Ng, Gao, Ren, Lai, Ren, *Contact-Aided Navigation of Flexible
Robotic Endoscope Using Deep Reinforcement Learning in Dynamic Stomach*.
Lengths here are in millimetres where the source quotes millimetres; the
model builders convert them once through :mod:`mjendo.units`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

# --------------------------------------------------------------------------
# Paper facts used as checks (not as free parameters).
PAPER_STOMACH_LENGTH_MM = 190.0  # paper: average adult male stomach length
PAPER_GREATER_CURVATURE_MM = 344.0  # paper: greater curvature length
PAPER_ACTIVE_SEGMENT_MM = 79.0  # paper: active bending segment
PAPER_N_FIXED = 3  # paper: 3 fixed vertex indices
PAPER_N_FORCED = 2  # paper: 2 forced vertex indices
PAPER_F0_N = 1.0  # paper: |f0| = 1 N square-wave force
PAPER_ALARM_DISTANCE_MM = 2.0  # paper: SOFA alarm distance (proximity search only: no MuJoCo counterpart)
PAPER_CONTACT_DISTANCE_MM = 0.5  # paper: SOFA contact distance
PAPER_FRICTION = 0.1  # paper: friction coefficient
GRAVITY = 9.8  # paper: m/s^2


@dataclass(frozen=True)
class StomachShape:
    """Parameters of the built-in J-shaped stomach (lumen centreline + radius).

    The defaults were tuned (``python -m mjendo.anatomy report``) so that the
    outer length and greater curvature match the paper's 190 mm and 344 mm
    within a few per cent.
    """

    fundus_radius_mm: float = 40.0  # dome over the cardia
    body_radius_mm: float = 40.0  # corpus, widest part
    body_length_mm: float = 50.0  # straight descending part after the dome
    bend_radius_mm: float = 50.0  # radius of the J's bottom (angular incisure)
    bend_angle_deg: float = 100.0  # how far the J turns back up
    antrum_radius_mm: float = 26.0  # radius where the antrum begins
    antrum_length_mm: float = 20.0  # straight antrum after the bend
    pylorus_radius_mm: float = 11.0  # closed pyloric end
    # A distended adult gastric wall measures about 3-5 mm; 5 mm keeps the
    # single-layer tets of a coarse mesh reasonably shaped.
    wall_thickness_mm: float = 5.0
    wall_layers: int = 1  # tet layers through the wall (the refinement study uses 2)
    n_around: int = 12  # vertices around each ring (even: both curvatures)
    ring_spacing_mm: float = 20.0  # target spacing of rings along the centreline
    # Cardia (gastro-oesophageal junction): on the lesser-curvature side, just
    # below the fundus dome; its opening is about 2.5-3 cm across.
    cardia_arclength_mm: float = 12.0
    cardia_radius_mm: float = 15.0


@dataclass(frozen=True)
class AnatomyRanges:
    """Ranges (mm, degrees) from which generated stomachs draw their StomachShape, each uniformly.

    Sources: MRI of healthy adults after a meal, stomachs 184-226 mm long and 65-102 mm across at their
    widest (4 subjects, "A novel method for time-dependent numerical modeling of gastric motility
    directly from magnetic resonance imaging", IEEE EMBC 2020); gastric volume varies between people by
    about a third fasting and a sixth fed (SPECT, 433 subjects, coefficient of variation 32.6 % / 16.0 %:
    Breen et al. 2011, Neurogastroenterol. Motil. 23: 308); wall thickness on CT 2.0 +- 0.4 mm in the
    distended body and 5.1 +- 1.6 mm in the antrum (Pickhardt and Asher 2003, AJR 181: 973). The bend
    of the J (the angular incisure) spans the J-shaped to the steer-horn stomach of anatomy texts; no
    measured distribution of it was found, so its range is a judgement, as are the antrum's and
    pylorus's (about a quarter either way of the built-in values).
    """

    fundus_radius_mm: tuple[float, float] = (32.0, 48.0)  # lumen; 65-102 mm across with the wall
    body_radius_mm: tuple[float, float] = (32.0, 48.0)
    body_length_mm: tuple[float, float] = (40.0, 80.0)  # with the rest: 184-226 mm long (measured per anatomy)
    bend_radius_mm: tuple[float, float] = (40.0, 60.0)
    bend_angle_deg: tuple[float, float] = (80.0, 120.0)  # J-shaped to steer-horn
    antrum_radius_mm: tuple[float, float] = (20.0, 32.0)
    antrum_length_mm: tuple[float, float] = (10.0, 35.0)
    pylorus_radius_mm: tuple[float, float] = (9.0, 13.0)
    # One tet layer: thinner than 4 mm flattens the tets of a 20 mm mesh (the refinement study's limit).
    wall_thickness_mm: tuple[float, float] = (4.0, 6.0)
    cardia_arclength_mm: tuple[float, float] = (8.0, 18.0)  # how far below the fundus dome the cardia opens


# The anatomy benchmark: generated stomachs (anatomy.generate) to train on, disjoint ones to choose seeds and
# checkpoints on ("val"), and disjoint ones to test on, drawn per episode by `anatomy="train"` / "val" / "test".
# The seeds are published so results compare. Stomach 204 is left out of "val": in the fast stomach the
# retracting scope strikes its wall at the cardia (scene.probe refuses it), so it has no map.
ANATOMY_SETS: dict[str, tuple[int, ...]] = {"train": tuple(range(0, 20)),
                                            "val": (200, 201, 202, 203, 205, 206, 207, 208, 209, 210),
                                            "test": tuple(range(100, 110))}


def anatomy_set(anatomy) -> tuple[int, ...] | None:
    """The seeds of a set of generated stomachs, or None for one stomach: a benchmark set's name (ANATOMY_SETS)
    or a list of your own, written as seeds and ranges ("110-119", "3,5,8-9"), for a held-out set of your own."""
    if not isinstance(anatomy, str):
        return None
    if anatomy in ANATOMY_SETS:
        return ANATOMY_SETS[anatomy]
    if not re.fullmatch(r"\d+(-\d+)?(,\d+(-\d+)?)*", anatomy) or ("," not in anatomy and "-" not in anatomy):
        return None
    seeds = []
    for part in anatomy.split(","):
        lo, _, hi = part.partition("-")
        if hi and int(hi) < int(lo):
            raise ConfigError(f"anatomy {anatomy!r}: the range {part} runs backwards; write it {hi}-{lo}")
        seeds += range(int(lo), int(hi or lo) + 1)
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"anatomy {anatomy!r} names a stomach twice: give each seed once")
    return tuple(seeds)


@dataclass(frozen=True)
class Material:
    """Linear elastic stomach wall (MuJoCo flex ``<elasticity>``)."""

    # Reported moduli of gastric wall span 1e3-1e6 Pa (indentation vs tensile,
    # strain level). We calibrated this value so that the paper's 1 N periodic load moves the
    # loaded wall by millimetres to about a centimetre (see docs/physics.md).
    young_pa: float = 150e3
    # Tissue is nearly incompressible (~0.45-0.49), but poisson near 0.45 on a
    # coarse single-layer mesh is ill-conditioned in MuJoCo; 0.3 is the
    # compromise (documented in docs/physics.md).
    poisson: float = 0.3
    # s; stiffness-proportional (Rayleigh beta) damping: tissue dissipation, so
    # the wall settles within ~0.1 s instead of ringing.
    damping: float = 0.03
    # 1/s; mass-proportional (Rayleigh alpha) damping: the drag of the viscera
    # around the stomach on its wall's absolute velocity. Without it the
    # stomach's slowest mode (8.7 rad/s, a swing about the fixed vertices)
    # rang at 1.4 Hz and the 10 ms step's numerical damping hid it, so wall
    # motion depended on the timestep (-29 % at 10 ms vs 2.5 ms). 15 = 2 w1 -
    # damping * w1^2: that mode critically damped (docs/physics.md "Damping").
    drag_per_s: float = 15.0
    # 1/s^2; mass-proportional elastic foundation: the organs around the stomach (liver, spleen, colon,
    # omentum) hold its wall near its place, a zero-length spring per flex dof of stiffness
    # foundation * mass. 0 (task version 0): only the 3 fixed vertices hold it, and a scope pushing with
    # its 10 N insertion force swung the whole fast stomach by 150-240 mm. See TaskVersion.
    foundation_per_s2: float = 0.0
    density_kg_m3: float = 1040.0  # soft tissue


@dataclass(frozen=True)
class Contact:
    """Paper's SOFA contact settings mapped onto MuJoCo.

    MuJoCo 3.17 ignores ``gap`` for geom-vs-flex contacts (measured: a 2 mm
    margin with a 1.5 mm gap pushed the scope from 2 mm away), so the margin
    is the paper's contact distance and the gap is 0. SOFA's alarm distance
    only selects the pairs its proximity search tests; it carries no force.
    SOFA's Lagrange-multiplier contact (no interpenetration) maps to MuJoCo's
    constraint solver with a hard impedance (docs/physics.md "Contact").
    """

    margin_mm: float = PAPER_CONTACT_DISTANCE_MM
    gap_mm: float = 0.0
    friction: float = PAPER_FRICTION
    solimp: tuple[float, float, float] = (0.95, 0.99, 0.001)


@dataclass(frozen=True)
class Endoscope:
    """Flexible robotic endoscope: chain of capsules, 4 cables, insertion slide."""

    diameter_mm: float = 9.8  # adult gastroscopes are about 9-10 mm
    active_length_mm: float = PAPER_ACTIVE_SEGMENT_MM
    n_active_links: int = 8
    # Only the part that can enter the stomach is simulated (paper's passive
    # segment is 1000 mm). It must reach from the cardia to the far wall.
    passive_length_mm: float = 200.0
    n_passive_links: int = 8
    cable_offset_mm: float = 3.5  # cable channel radius inside the 9.8 mm tube
    # Bending stiffness EI. Active bending sections are far softer than the
    # insertion tube; values of this order are reported for gastroscopes.
    active_EI_Nm2: float = 0.004
    passive_EI_Nm2: float = 0.03
    linear_density_kg_m: float = 0.1  # ~100 g per metre of insertion tube
    # Numerical mass scaling of the joints (like SOFA's quasi-static solve):
    # lets the chain run at the scene timestep without changing statics.
    joint_armature: float = 2e-5
    joint_damping: float = 2e-3  # N m s / rad
    cable_max_tension_n: float = 40.0
    cable_kp_n_per_m: float = 8000.0  # cable servo stiffness (position control)
    insertion_kp_n_per_m: float = 2000.0  # stiff insertion servo (a motorised feeder)
    insertion_damping: float = 25.0  # N s / m, about critical for the carriage
    insertion_max_force_n: float = 10.0
    # Withdrawal past the cardia (below -start_depth) is possible: leaving the
    # stomach is a real failure mode the task penalises.
    insertion_range_mm: tuple[float, float] = (-30.0, 160.0)
    # Where the tip starts at insertion 0: this far past the cardia opening.
    start_depth_mm: float = 20.0
    # The oesophageal hiatus holds the insertion tube at the cardia like a compliant pivot: the tube
    # tilts about the cardia instead of running on a rigid straight slide. A torsional spring per bending
    # plane (N m / rad) with a range; None keeps the rigid slide (task version 0). No measured value of the
    # hiatus' angular stiffness is published; 0.02 N m/rad lets the fully inserted tube's own weight
    # (0.1 kg/m x 0.18 m) tilt it by about 40 degrees across gravity (docs/physics.md "Scope").
    pivot_stiffness_Nm_per_rad: float | None = None
    pivot_damping: float = 0.01  # N m s / rad: the oesophagus around the tube; settles the tilt within 0.2 s
    pivot_range_deg: float = 60.0  # the hiatus cannot open further (mechanical stop, not a spring)
    hiatus_clearance_mm: float = 0.5  # radial play of the tube in the ring that models the hiatus


MAX_TIMESTEP_S = 0.05  # above this no stomach's contact resolves a scope tip moving at its speeds


@dataclass(frozen=True)
class Fidelity:
    """How the stomach's flex degrees of freedom are resolved."""

    name: str
    dof: str  # MuJoCo flex dof: "trilinear" (reduced order) or "full"
    cellcount: tuple[int, int, int] = (1, 1, 1)  # trilinear grid cells
    # The discrete integrator (implicit in stiffness and damping) stays stable
    # far beyond this on our meshes; 10 ms keeps contact resolution at 1 mm
    # per step for a 0.1 m/s tip (measured: docs/physics.md).
    timestep_s: float = 0.01
    # The discrete integrator solves M + hD + h^2 K iteratively with the same
    # iteration cap and tolerance as the constraint solver. An under-converged
    # solve feeds energy in: at 1e-4 the full stomach never came to rest under
    # a held press (tip 24 mm/s, wall 29 mm/s). Since the wall drag
    # (Material.drag_per_s) both stomachs settle at 1e-6: held presses in
    # full 0.05-0.27 mm/s (1e-8: 0.00-0.05), every press force within 3 % and
    # every target motion within 0.01 mm of 1e-8's, 1.4x the speed of 1e-8 in
    # the contact-rich sweep (`python -m mjendo.fidelity solver`,
    # docs/physics.md). 1e-5 leaves the fast one creeping at 1-6 mm/s. The
    # cap binds on 15 % of sweep steps (the contact solve, not M + hD + h^2 K);
    # caps of 200-300 leave the M + hD + h^2 K solve unconverged on most
    # contact steps and 150 breaks a deep press.
    iterations: int = 1000
    tolerance: float = 1e-6
    # MuJoCo's constraint solver. CG suits the full stomach's 822 dofs (Newton's
    # dense Hessian ran at 0.48x against CG's 0.65x); the fast stomach's 114 are
    # cheap to factor, and Newton converges there in 2-6 iterations (CG: median
    # 58, up to the cap), 1.5x the speed at the same forces and motion
    # (docs/physics.md "Solver").
    solver: str = "CG"
    # Constraint Jacobian storage (MuJoCo's option; the task version sets the fast stomach's).
    jacobian: str = "auto"
    # Reduced-order stomachs are stiffer than the mesh they interpolate
    # (locking). This factor on young's modulus was calibrated so that the
    # periodic load moves the forced vertices as far as in the full model
    # (docs/physics.md; `make bench` prints the wall motion of each scene).
    young_scale: float = 1.0
    # Reduced-order stomachs respond to the point load through their few grid
    # nodes, not through the wall around the loaded vertices: matching the
    # contact stiffness (young_scale) leaves the load-driven motion too small.
    # This gain on the periodic load calibrates that global mode separately, so
    # target motion matches the full model too (docs/physics.md). One gain per
    # load level (1, 2, 3 x f0: DE, UE1, UE2; interpolated between): the full
    # stomach softens under large loads (its UE2 motion is 4.5x DE's for 3x the
    # load), the trilinear one does not (2.8x). Named stomachs take theirs from
    # TaskVersion.fast_load_gains (per grid); a Fidelity given as such keeps its own.
    load_gains: tuple[float, float, float] = (1.0, 1.0, 1.0)
    # Impedance (MuJoCo solimp: dmin, dmax, width in m) of the scope-wall contact; None: Contact.solimp.
    # A wall interpolated on 27 nodes cannot give locally under the tube lying on it as the FEM wall does;
    # a softer contact carries that give, calibrated on the tip's path under the same open-loop motions
    # (`python -m mjendo.fidelity tracks`, docs/physics.md "Where the wall leaves the tube").
    contact_solimp: tuple[float, float, float] | None = None
    first_version: int = 0  # the first task version with this stomach (older versions' scenes predate it)
    description: str = ""  # what reports call this stomach


LOAD_LEVELS = (1.0, 2.0, 3.0)  # x f0: the paper's DE, UE1, UE2


def wall_solimp(compliance: float) -> tuple[float, float, float]:
    """Scope-wall contact impedance a share ``compliance`` of the way from the fast stomach's (0) to
    fast-compliant's (1), each of dmin, dmax and width linearly (Randomization.wall_compliance)."""
    stiff, soft = np.array(Contact().solimp), np.array(FIDELITIES["fast-compliant"].contact_solimp)
    return tuple(float(x) for x in stiff + compliance * (soft - stiff))


def load_gain(gains, multiplier: float) -> float:
    """Gain on the periodic load at ``multiplier`` x f0, from the gains at LOAD_LEVELS."""
    return float(np.interp(multiplier, LOAD_LEVELS, gains))


FIDELITIES: dict[str, Fidelity] = {
    # Default: reduced-order stomach, interpolated on a trilinear grid (also
    # supported by MuJoCo Warp); collision still uses the full mesh.
    # young_scale was calibrated against "full" with `python -m mjendo.fidelity`
    # (docs/physics.md "Calibration"): press forces within 1.25x (0.5 mm contact);
    # its load gains (target motion) are the task version's (TaskVersion.fast_load_gains).
    "fast": Fidelity("fast", "trilinear", (2, 2, 2), young_scale=0.05,
                     solver="Newton", description="the fast (reduced-order, calibrated) stomach"),
    # The fast stomach with the contact impedance that puts its tip where the FEM stomach's goes under the
    # same motions: tip paths 1.3 mm from the full stomach's on average against 2.3 (docs/physics.md).
    "fast-compliant": Fidelity("fast-compliant", "trilinear", (2, 2, 2), young_scale=0.05,
                               solver="Newton", contact_solimp=(0.3, 0.99, 0.005),
                               first_version=1, description="the fast stomach with the contact calibrated to the "
                               "full stomach's tip paths"),
    # The fast stomach on one trilinear cell (8 nodes, 24 dofs): 1.6x the env steps/s under a trained policy, the
    # same press forces within 1.3x and median target motion; its targets move as one block (docs/physics.md
    # "A one-cell fast stomach"). A candidate for training throughput, not the task's default.
    "fast-coarse": Fidelity("fast-coarse", "trilinear", (1, 1, 1), young_scale=0.05, solver="Newton", first_version=1,
                            description="the fast stomach on one trilinear cell (8 nodes)"),
    # Every mesh vertex is a 3-dof body: the per-vertex FEM stomach.
    "full": Fidelity("full", "full", (1, 1, 1), description="the full per-vertex FEM stomach"),
}


@dataclass(frozen=True)
class PeriodicLoad:
    """Square-wave force on the forced vertices (breathing / motility)."""

    f0_n: float = PAPER_F0_N
    # Half period T (the wave's period is 2T). The paper gives no value;
    # 2 s gives a 4 s cycle, i.e. 15 breaths per minute.
    half_period_s: float = 2.0
    # Diaphragm excursion in breathing is mostly cranio-caudal: push along z.
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class Randomization:
    """Per-episode ranges of the stomach's tissue and motion and of sensor noise (domain randomization).

    Scales multiply the scene's calibrated values, so the fast and the full stomach randomize alike.
    Each episode draws every factor independently (log-uniform for the moduli, uniform for the rest).
    """

    # Young's modulus of the wall (and its stiffness-proportional damping with it): gastric wall moduli
    # differ several-fold by region, layer, direction and species (porcine biaxial tests: corpus stiffest,
    # fundus softest, Bauer et al. 2020, Acta Biomater. 116; human vs porcine, Friis et al. 2023, J. Mech.
    # Behav. Biomed. Mater. 138; layer- and orientation-dependence, Jia et al. 2015, J. Biomech. 48: 651):
    # a factor 3 either way of the calibrated modulus (Material.young_pa).
    young_scale: tuple[float, float] = (1 / 3, 3.0)
    # Tissue damping (Material.damping, Rayleigh beta): relaxation differs by region and layer as much as
    # stiffness does (the same studies' stress-relaxation tests); a factor 2 either way.
    damping_scale: tuple[float, float] = (0.5, 2.0)
    # Breathing load amplitude, x the condition's (f0, 2 f0, 3 f0): tidal volume and so diaphragm excursion
    # vary from breath to breath and patient to patient; half to one and a half times.
    load_scale: tuple[float, float] = (0.5, 1.5)
    # Half period of the square wave: resting adults breathe 12-20 times a minute (cycle 3-5 s).
    half_period_s: tuple[float, float] = (1.5, 2.5)
    # Direction of the load within a cone about the cranio-caudal axis: abdominal organs move mostly
    # cranio-caudally with breathing, with an antero-posterior component up to about half of it
    # (Langen and Jones 2001, Int. J. Radiat. Oncol. Biol. Phys. 50: 265): up to 30 degrees.
    load_tilt_deg: float = 30.0
    # Scope-mucosa friction about the paper's 0.1: mucus-lubricated gastrointestinal mucosa gives
    # coefficients of a few hundredths to a few tenths (Accoto et al. 2001, on GI friction for locomotion).
    friction: tuple[float, float] = (0.05, 0.3)
    # Sensor noise (standard deviations) on the observation: tip force sensors of flexible instruments
    # resolve tens of mN; electromagnetic trackers locate a tip to about 1 mm RMS.
    force_noise_n: float = 0.02
    target_noise_mm: float = 1.0
    # After new tissue and load parameters are set the wall is let settle this long (the scope held
    # straight at the cardia) before the episode's first observation: it settles within about 0.5 s.
    settle_s: float = 0.5
    # Scope-wall contact impedance, drawn as a share of the way from the fast stomach's (Contact.solimp: 0)
    # to the one calibrated on the FEM wall's tip paths (fast-compliant's contact_solimp: 1). Under a
    # policy's own motions these two stomachs put the tip about 1 mm either side of the FEM wall's path
    # (docs/physics.md "Under a policy's own motions"), so the range covers that model error. None: the
    # scene's own impedance (the default).
    wall_compliance: tuple[float, float] | None = None
    # Actuation error: each step the executed cable and insertion increments differ from the commanded ones
    # by this relative standard deviation, drawn per increment. Tendon-sheath drives of flexible endoscopes
    # transmit cable motion with friction, slack and backlash (Do et al. 2014, Mechatronics 24: 12), and a
    # policy whose steps land only under exact kinematics loses trials to about 1 mm of model error
    # (docs/physics.md "Under a policy's own motions"). A training lever, not a calibration: 0 (the
    # default) executes every command exactly.
    actuation_noise: float = 0.0
    # Physics steps (s) an episode runs at, one drawn per episode with equal chances; None: the task's own. The
    # fast stomachs run at 20 ms and the full one at 10 ms, and a policy trained at one step loses a fifth of its
    # trials at the other in any stomach (docs/physics.md "Timestep"): drawing both trains across that model
    # error. A training lever, not a tissue property.
    physics_step_s: tuple[float, ...] | None = None
    # Local give of the wall at the target (mm per N of the scope's push on the wall nearby), drawn per episode;
    # None: none beyond the stomach's own. The reduced-order walls move as trilinear blocks and cannot dent: in
    # SE under the shipped E, once the scope touches the wall, list A's contact-aided targets move 0.60 mm
    # (median; 90th percentile 1.17) in the FEM wall and 0.18 (0.33) in fast-coarse at the same 10 ms step, and
    # fitted to the scope's contact forces within target_give_sigma_mm of the target, 1.76 against 0.71 mm/N
    # (docs/physics.md "Targets give under the scope"). The drawn give displaces the target by that many mm per N
    # of the push, Gaussian-weighted by each contact's distance: a training lever across that model error.
    target_give_mm_per_n: tuple[float, float] | None = None
    target_give_sigma_mm: float = 20.0

    # Any of these set to None keeps the scene's value instead of drawing one.
    RANGES = ("young_scale", "damping_scale", "load_scale", "half_period_s", "friction", "wall_compliance",
              "target_give_mm_per_n")

    def check(self) -> Randomization:
        """This randomization, or a ConfigError naming the bad range."""
        for name in self.RANGES:
            r = getattr(self, name)
            if r is None:
                continue
            ok = isinstance(r, tuple | list) and len(r) == 2 and all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in r)
            # a share of the way (wall_compliance) lies in [0, 1], a give may be 0, the scales are positive
            zero_ok, top = {"wall_compliance": (True, 1.0), "target_give_mm_per_n": (True, math.inf)}.get(
                name, (False, math.inf))
            bounds = f"0 {'<=' if zero_ok else '<'} low <= high" + (" <= 1" if top == 1.0 else "")
            if not ok or not ((0 <= r[0] if zero_ok else 0 < r[0]) and r[0] <= r[1] <= top):
                raise ConfigError(f"randomization {name} must be None or a range (low, high) with {bounds}, "
                                  f"not {r!r}")
        for name, hi in (("load_tilt_deg", 90.0), ("force_noise_n", math.inf), ("target_noise_mm", math.inf),
                         ("settle_s", math.inf), ("actuation_noise", 1.0), ("target_give_sigma_mm", math.inf)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not 0 <= v <= hi:
                raise ConfigError(f"randomization {name} must be a number in [0, {hi:g}], not {v!r}")
        steps = self.physics_step_s
        if steps is not None and (not isinstance(steps, tuple | list) or not steps or not all(
                isinstance(x, int | float) and not isinstance(x, bool) and 0 < x <= MAX_TIMESTEP_S for x in steps)):
            raise ConfigError(f"randomization physics_step_s must be None or a list of steps in (0, "
                              f"{MAX_TIMESTEP_S}] s, not {steps!r}")
        return replace(self, physics_step_s=None if steps is None else tuple(float(x) for x in steps),
                       **{n: None if getattr(self, n) is None else tuple(float(x) for x in getattr(self, n))
                          for n in self.RANGES})

    def draw(self, rng: np.random.Generator, nominal_direction) -> dict:
        """One episode's parameters: scales, half period (s), load direction (unit vector), friction, wall
        compliance, the target's give; None for a range that is not drawn (the scene's value)."""
        def log_uniform(r):
            return None if r is None else float(np.exp(rng.uniform(np.log(r[0]), np.log(r[1]))))

        def uniform(r):
            return None if r is None else float(rng.uniform(*r))

        n = np.asarray(nominal_direction, float)
        n = n / np.linalg.norm(n)
        # Uniform on the spherical cap of half-angle load_tilt_deg about the nominal direction.
        cos_t = rng.uniform(math.cos(math.radians(self.load_tilt_deg)), 1.0)
        side = np.cross(n, rng.normal(size=3))
        side /= np.linalg.norm(side)
        direction = cos_t * n + math.sqrt(max(0.0, 1.0 - cos_t**2)) * side
        return {"young_scale": log_uniform(self.young_scale), "damping_scale": log_uniform(self.damping_scale),
                "load_scale": uniform(self.load_scale), "half_period_s": uniform(self.half_period_s),
                "load_direction": direction, "friction": uniform(self.friction),
                "wall_compliance": uniform(self.wall_compliance),
                "target_give_mm_per_n": uniform(self.target_give_mm_per_n),
                "physics_step_s": None if self.physics_step_s is None else float(rng.choice(self.physics_step_s))}


@dataclass(frozen=True)
class Condition:
    """One of the paper's five task conditions ("environments" FE, SE, DE, UE1, UE2).

    Conditions share their scene: SE, DE, UE1 and UE2 differ only in the
    periodic load's amplitude, which the Simulator sets when it starts.
    """

    name: str
    has_stomach: bool
    load_multiplier: float  # times f0 (0: no periodic force)
    target_list: str  # "A" (training) or "B" (held out)


CONDITIONS: dict[str, Condition] = {
    "FE": Condition("FE", False, 0.0, "A"),  # paper: free environment, targets float where the wall would be
    "SE": Condition("SE", True, 0.0, "A"),  # paper: static stomach
    "DE": Condition("DE", True, 1.0, "A"),  # paper: dynamic, f0
    "UE1": Condition("UE1", True, 2.0, "B"),  # paper: unstructured, 2 x f0, unseen targets
    "UE2": Condition("UE2", True, 3.0, "B"),  # paper: unstructured, 3 x f0, unseen targets
}


@dataclass(frozen=True)
class SceneConfig:
    """Everything one scene file is built from: with or without the stomach, at one fidelity."""

    has_stomach: bool
    fidelity: Fidelity
    material: Material = field(default_factory=Material)
    contact: Contact = field(default_factory=Contact)
    endoscope: Endoscope = field(default_factory=Endoscope)
    load: PeriodicLoad = field(default_factory=PeriodicLoad)
    gravity: float = GRAVITY
    # Unit direction of gravity in the stomach's frame (z cranial, -x the patient's left, where the greater
    # curvature lies). (0, 0, -1): upright (task version 0). Upper GI endoscopy is done with the patient in
    # the left lateral decubitus position, so gravity points to the patient's left, -x (docs/physics.md).
    gravity_direction: tuple[float, float, float] = (0.0, 0.0, -1.0)

    def young_pa(self) -> float:
        """Young's modulus used by this scene's flex (fidelity-calibrated)."""
        return self.material.young_pa * self.fidelity.young_scale


class ConfigError(ValueError):
    """A configuration value is unknown or physically unusable."""


def _pick(table: dict, key: str, what: str):
    if key not in table:
        raise ConfigError(f"unknown {what} {key!r}; valid: {', '.join(map(str, table))}")
    return table[key]


def condition(env: str) -> Condition:
    """The task condition of an environment name, or a ConfigError listing the valid ones."""
    return _pick(CONDITIONS, env, "environment")


def fidelity_preset(fidelity: str | Fidelity, version: int | None = None) -> Fidelity:
    """A fidelity by name (the fast stomachs' timestep is the task version's) or as given."""
    if isinstance(fidelity, Fidelity):
        return fidelity
    fid = _pick(FIDELITIES, fidelity, "fidelity")
    version = CURRENT_VERSION if version is None else version
    if version < fid.first_version:
        older = " or ".join(repr(f) for f, x in FIDELITIES.items() if x.first_version <= version)
        raise ConfigError(f"the {fid.name!r} stomach exists from task version {fid.first_version}; "
                          f"version {version} runs in {older}")
    if fid.dof == "trilinear":
        ver = task_version(version)
        gains = ver.fast_load_gains.get(fid.cellcount)
        if gains is None:
            raise ConfigError(f"the {fid.name!r} stomach's grid {fid.cellcount} has no load calibration in task "
                              f"version {version}; calibrate it (python -m mjendo.fidelity compare --cells ...)"
                              " and add its gains to TaskVersion.fast_load_gains")
        fid = replace(fid, timestep_s=ver.fast_timestep_s, load_gains=gains, jacobian=ver.fast_jacobian)
    return fid


def scene_config(env: str = "DE", fidelity: str | Fidelity = "fast", version: int | None = None,
                 **overrides) -> SceneConfig:
    """The scene an environment runs in at a fidelity preset (name, or a Fidelity to try one)."""
    ver = task_version(CURRENT_VERSION if version is None else version)
    cfg = SceneConfig(has_stomach=condition(env).has_stomach, fidelity=fidelity_preset(fidelity, version),
                      endoscope=ver.endoscope, gravity_direction=ver.gravity_direction,
                      material=Material(foundation_per_s2=ver.foundation_per_s2))
    return replace(cfg, **overrides) if overrides else cfg


# --------------------------------------------------------------------------
# The learning problem (paper's MDP).
POLICY_NAMES = ("A", "B", "C", "D", "E")  # paper: the five policies (train/policies.yaml configures them)
PAPER_ACTION_LIMIT = 0.4  # paper: actions in [-0.4, 0.4]
ACTION_SIZE = 5  # paper: four cable commands and one axial (insertion) command
PAPER_SUCCESS_MM = 3.0  # paper: success when the tip is within 3 mm
PAPER_BONUS = 1e4  # paper: R_S = +1e4 on success, R_B = -1e4 on leaving
PAPER_EXIT_X_MM = 15.0  # paper: x_EE < 15 mm in its frame means the tip left
PAPER_TRAIN_STEPS = 128  # paper: training episode length
PAPER_EVAL_STEPS = 80  # paper: evaluation trial length


# --------------------------------------------------------------------------
# Time scales of the task (task version 1), from the literature; none was tuned for success.
# Breathing: 12-20 breaths/min in resting adults (clinical normal range); PeriodicLoad's 4 s cycle is 15/min.
# Gastric motility: the gastric slow wave and antral contractions run at about 3 per minute (20 s period).
# Heartbeat: 60-100 /min. The square-wave load is the breathing component (the largest excursion).
# Flexible robotic endoscopes move their tips at millimetres to a few centimetres per second: insertion
# of manual and robotic gastroscopes runs at about 1-3 cm/s and bending sections sweep tens of degrees
# per second. Version 1 caps insertion at 25 mm/s and the cable stroke at 4 mm/s (full bending in
# about 2.3 s, 65 degrees/s), and controls at 10 Hz: an 80-step trial lasts 8 s, two breathing cycles.
CONTROL_PERIOD_S = 0.1
# Observations a history_obs policy sees besides the current one (TaskConfig.history_obs): four, as Atari's
# frame stacks; at 10 Hz the last 0.4 s, a tenth of a breathing cycle.
HISTORY_STEPS = 4
# residual: the policy's action, times this, is added to the baseline's; 2 lets it reverse a saturated baseline
# command (0.4 + 2 x -0.4 = -0.4), which the wall's strategies need (retract where the baseline inserts). Ours.
RESIDUAL_GAIN = 2.0
# task_space: the policy's three action values, times this, are the tip displacement (mm, world frame) the DLS
# controller is asked for; at the 0.4 limit 10 mm, more than one control step moves the tip (insertion 2.5 mm,
# a bending sweep 2-3 mm), so a saturated command asks for the joints' full step as the baseline's does. Ours.
TASK_SPACE_MM_PER_UNIT = 25.0
TASK_SPACE_SIZE = 3  # task_space: the tip displacement's three world components
# depth_obs (TaskConfig.depth_obs): how far the tip camera's lens (4 mm behind the tip face) sees the lumen wall
# along five rays, the tip axis and four tilted towards the bending planes. Gastroscopes image 140 degrees
# (Olympus GIF-H190, a 70 degree half-angle; the tip camera here is 100), so a 30 degree tilt is well inside the
# picture; their depth of field ends at 100 mm (GIF-H190: 2-100 mm), beyond which a ray reads its range, as one
# that meets no wall.
DEPTH_TILT_DEG = 30.0
DEPTH_RANGE_MM = 100.0
INSERTION_MM_PER_S = 25.0
CABLE_MM_PER_S = 4.0
# A safety-limited feeder: the insertion servo pushes with 3 N at most. With the 10 N of version 0 a scope
# buckled against the greater curvature pushed the whole stomach 100-240 mm away (measured).
INSERTION_MAX_FORCE_N = 3.0
# The organs around the stomach hold it (Material.foundation_per_s2): 2000 /s^2 on its 0.23 kg is about
# 460 N/m in all, so the 3 N feeder can displace the whole organ by about 7 mm, the 1 N breathing load
# by about 2 mm, on top of the wall's local deformation. With none, 3 anchor vertices held the stomach.
FOUNDATION_PER_S2 = 2000.0


@dataclass(frozen=True)
class TaskVersion:
    """What changed between task versions: scope, patient position, time scales, fast timestep, targets.

    Version 0 is the first release's task (rigid straight slide, upright gravity, 30 ms control
    period, 133 mm/s insertion, vertex targets); it stays selectable so its tables can be reproduced.
    """

    endoscope: Endoscope
    gravity_direction: tuple[float, float, float]
    foundation_per_s2: float
    fast_timestep_s: float
    # Fidelity.load_gains of each calibrated trilinear grid (cellcount): the reduced-order stomachs'
    # periodic load is calibrated per task version and grid (docs/physics.md "Calibration")
    fast_load_gains: dict[tuple[int, int, int], tuple[float, float, float]]
    control_period_s: float
    cable_mm_per_unit: float
    insertion_mm_per_unit: float
    # Dense suits the fast stomach's 116 dofs from version 1: its DE env steps run 1.18x as fast as
    # under "auto" (sparse there) with the same physics (medians of 3 alternating runs of 600 random
    # steps); the full stomach's 822 stay sparse. Version 0 keeps its scenes byte for byte.
    fast_jacobian: str = "auto"
    # A version that is an alternative to the current one rather than its successor gets a name of its own in its
    # Gymnasium ids (mjendo/DE-<tag>-v2): Gymnasium takes an id's highest version as the latest, so a plain
    # mjendo/DE-v2 would make mjendo/DE resolve to it and mjendo/DE-v1 warn that it is out of date.
    gym_tag: str = ""


VERSIONS: dict[int, TaskVersion] = {
    0: TaskVersion(Endoscope(), (0.0, 0.0, -1.0), 0.0, 0.01, {(2, 2, 2): (4.1, 5.7, 6.3)}, 0.03, 2.5, 10.0),
    # 20 ms: 5 physics steps per 100 ms control step. The bending section's hinge modes (1.2 N m/rad on
    # 2e-5 kg m^2: 39 Hz) sit above what any of these steps resolves; they rang under contact and set off
    # numerical events (driven into the wall, bang-bang: 0.09 % of steps above 10 N, the tip jumping 47 mm
    # in one control step, up to 3.9 m/s, at 12.5 ms). Armature 1e-3 kg m^2 (5.5 Hz, the chain still
    # answers a cable command within a control step; the cardia pivot's hinges too) and damping
    # 0.01 N m s/rad on the bending hinges remove them: no step above 10 N, tip at most 0.67 m/s, at
    # 20 ms; held presses settle (0.10 mm/s after 4 s) with forces within 11 % of the lighter chain's.
    # At 25 ms an end-on press still never settles (15 mm/s after 4 s) (docs/physics.md "Timestep").
    1: TaskVersion(Endoscope(pivot_stiffness_Nm_per_rad=0.03, insertion_max_force_n=INSERTION_MAX_FORCE_N,
                             joint_armature=1e-3, joint_damping=0.01),
                   # load gains: median target motion over a load cycle as in the full stomach (docs/physics.md);
                   # the one-cell grid (fast-coarse) answers the load through 8 nodes only, hence its gains of 14
                   (-1.0, 0.0, 0.0), FOUNDATION_PER_S2, 0.02,
                   {(2, 2, 2): (2.85, 2.91, 2.98), (1, 1, 1): (13.76, 14.02, 14.33)}, CONTROL_PERIOD_S,
                   CABLE_MM_PER_S * CONTROL_PERIOD_S / PAPER_ACTION_LIMIT,
                   INSERTION_MM_PER_S * CONTROL_PERIOD_S / PAPER_ACTION_LIMIT, fast_jacobian="dense"),
}
# Version 2: version 1 at the full FEM stomach's 10 ms step in the fast stomachs too (10 physics steps per control
# step), and a map measured there. MuJoCo raises a soft constraint's time constant to at least two steps, so at
# 20 ms the scope-wall contacts (0.02 s) and the fast stomach's anchors (0.01 s) act at 0.04 s: a softer wall than
# the one configured, through which the fastest of the map's 180 demonstrators reached all of version 1's list A
# contact-aided targets from SE and four DE phases, and at 10 ms 28 of 42 (85.2 % of the 210 pairs;
# `python -m mjendo.targets slack --list A --fastest --timestep 0.01`). The full stomach, the model of record,
# runs at 10 ms (its target motion there within 6 % of 5 ms): the targets must be reachable at its step.
# Load gains scaled so each load level's median target motion at 10 ms equals version 1's at 20 ms
# (`mjendo.fidelity.motion_summary` on a Fidelity with timestep_s 0.01 and 0.02: fast 3.33 / 3.14 mm in DE,
# fast-coarse 3.13 / 3.14).
VERSIONS[2] = replace(VERSIONS[1], fast_timestep_s=0.01,
                      fast_load_gains={(2, 2, 2): (2.69, 2.76, 2.84), (1, 1, 1): (13.83, 14.09, 14.41)},
                      gym_tag="10ms")
CURRENT_VERSION = 1


def task_version(version: int) -> TaskVersion:
    return _pick(VERSIONS, version, "task version")


@dataclass(frozen=True)
class TaskConfig:
    """One navigation task: which scene, what the agent sees, how actions scale.

    The action scales and the control period default to the task version's (None): see TaskVersion.
    """

    env: str = "DE"
    fidelity: str = "fast"
    force_obs: bool = True  # contact indicator + resultant force (policies C, E)
    # The force sensor reads nothing (contact 0, force 0) while a force-aware policy keeps its inputs: the
    # ablation that says how much of what such a policy does it draws from them (evaluation --force-off).
    force_off: bool = False
    # Insertion depth, tip position and tip axis: more of the scope's state than the paper's policies
    # see (a real robot knows its insertion; the tip pose comes from the tracker that ee_to_target needs).
    scope_obs: bool = False
    # The share of the trial still left (Pardo et al. 2018, "Time Limits in Reinforcement Learning": under a fixed
    # limit a policy that does not see the time cannot know how much is left). With it the limit is part of the
    # MDP: reaching max_steps terminates the episode instead of truncating it.
    time_obs: bool = False
    # The breathing cycle's phase (sine and cosine): clinical systems measure it (a respiratory belt or the
    # ventilator; respiratory gating, Keall et al. 2006, AAPM TG-76, Med. Phys. 33: 3874). A policy that sees
    # the wall only through the target vector and the force cannot tell how long the wall will stay where it is.
    phase_obs: bool = False
    # What the last control step did: the four cable actions it commanded (the insertion one is observed already) and
    # the tip's displacement over it. A memoryless policy then sees how far its last command moved the tip, the
    # local gain of its actions, which the wall's give changes from stomach to stomach (not the paper's).
    step_obs: bool = False
    # The last HISTORY_STEPS observations before this one, newest first (frame stacking, as Mnih et al. 2015,
    # Nature 518: 529, stack four frames). A memoryless policy sees the wall only where the tip touches it now; a
    # stomach it has not seen shows its shape and give in how force and tip moved under the last commands.
    history_obs: bool = False
    # How far the wall is along five rays from the tip camera (DEPTH_TILT_DEG, DEPTH_RANGE_MM): what the endoscope's
    # own camera shows of the lumen ahead, as a depth map (stereo or monocular depth estimation) would give it. A policy
    # that sees the wall only where the tip touches it cannot tell, in a stomach it has not seen, where the wall it
    # needs is (not the paper's).
    depth_obs: bool = False
    # The lumen surface's normal at the target: which way the mucosa there faces, as the tip camera's picture of
    # the target (its depth map's surface orientation) shows it. In one stomach the target's position implies it;
    # in a stomach the policy has not seen, it tells from which side the target must be approached, and so
    # whether the wall is in the way (not the paper's).
    normal_obs: bool = False
    # The stomach map's plan for the target (targets.json: measured for every stomach before any trial, as planning
    # on the patient's pre-operative CT would): its free-space distance, whether it needs the wall, and the scripted
    # way the map found to it in the static stomach (targets.plan_vector). In one stomach a target's position
    # implies it; in a stomach the policy has not seen, it says at the first step whether and how the wall must be
    # used (not the paper's).
    plan_obs: bool = False
    # The action corrects a classic controller's instead of replacing it (residual policy learning: Silver et al.
    # 2018, arXiv:1812.06298; Johannink et al. 2019, ICRA): the applied action is the damped-least-squares
    # baseline's (mjendo.baseline) plus RESIDUAL_GAIN times the policy's, clipped to the box, and the baseline's
    # action is observed. The baseline aims in free space in any stomach without training; the policy learns where
    # the wall must be used (not the paper's).
    residual: bool = False
    # The action is a tip displacement in the world frame (TASK_SPACE_SIZE values, TASK_SPACE_MM_PER_UNIT mm each)
    # that the damped-least-squares controller (mjendo.baseline) turns into cable and insertion commands
    # (operational-space control, Khatib 1987): the policy chooses where the tip goes, the controller's
    # kinematic model how, so the aim needs no learning and the policy spends its samples on the wall (not the
    # paper's). Exclusive with residual.
    task_space: bool = False
    target_list: str | None = None  # None: the environment's own list (A or B); "A+F": lists joined
    max_steps: int = PAPER_TRAIN_STEPS
    version: int = CURRENT_VERSION  # task version (VERSIONS): scope, gravity, time scales, targets
    # Control period (paper: not given) and action unit -> physical increment per control step.
    control_period_s: float | None = None
    cable_mm_per_unit: float | None = None
    insertion_mm_per_unit: float | None = None
    force_ref_n: float = 1.0  # the observation's force is force / force_ref
    force_penalty: float = 0.0  # optional safety term: -force_penalty * |F| (N) per step
    # Weight of the paper's distance term (-distance_weight * mm per step); the paper's is 1. Below 1 the
    # success bonus outweighs the path's distances: a training choice (variants), success is measured alike.
    distance_weight: float = 1.0
    # Distance (mm) at which a training episode succeeds; the paper's is 3. Below it the policy must place the tip
    # more finely than the trial asks (a margin), a training choice (variants): every trial succeeds at 3 mm.
    success_mm: float = PAPER_SUCCESS_MM
    randomize_phase: bool = True  # start each episode at a random phase of the load
    # Per-episode tissue, load and friction and sensor noise (Randomization); None: the built-in stomach.
    # task_config also takes True (the default ranges) or a dict of Randomization fields.
    randomization: Randomization | None = None
    # Which stomach: None the built-in one; a whole number a generated one (anatomy.generate, its seed);
    # a set ("train", "val", "test" of ANATOMY_SETS, or seeds as "110-119"), drawn per episode by the environment;
    # a path a folder built by `python -m mjendo.anatomy build` (yours) with its target map.
    anatomy: int | str | None = None
    # Physics step (s) instead of the stomach's own (Fidelity.timestep_s; None: that one). The fast stomachs run at
    # 20 ms from task version 1 and the full one at 10 ms, and MuJoCo stiffens every soft constraint whose time
    # constant it had raised to two steps: a policy's success depends on the step (docs/physics.md "Timestep").
    timestep_s: float | None = None
    # Time constant (s) of the scope-wall contacts and the fast stomachs' anchors (their solref; None: the scene's,
    # 20 and 10 ms), set as the scene loads. MuJoCo raises a time constant to two physics steps, its floor for
    # stability; at 40 ms paper-step keeps its 10 ms level at 5 ms, not at 2.5 ms (docs/physics.md "Finer steps").
    contact_time_constant_s: float | None = None


TARGET_LISTS = ("A", "B", "F")  # training, held out, free-space (FE's own from version 1)


def default_target_list(env: str, version: int) -> str:
    """An environment's own list: FE aims at free-space targets (list F) from version 1, at A before."""
    return "F" if env == "FE" and version >= 1 else condition(env).target_list


def _finite(name: str, value, low: float, *, strict: bool) -> None:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) \
        and (value > low if strict else value >= low)
    if not ok:
        raise ConfigError(f"{name} must be a finite number {'>' if strict else '>='} {low:g}, not {value!r}")


def task_config(**kw) -> TaskConfig:
    """A TaskConfig with every field checked: names, types and ranges, each error naming the fix."""
    known = {f.name for f in fields(TaskConfig)}
    unknown = sorted(set(kw) - known)
    if unknown:
        raise ConfigError(f"unknown task argument(s) {', '.join(unknown)}; valid: {', '.join(sorted(known))}")
    cfg = TaskConfig(**kw)
    condition(cfg.env)
    fidelity_preset(cfg.fidelity)
    if isinstance(cfg.version, bool) or not isinstance(cfg.version, int | np.integer):
        raise ConfigError(f"version must be a whole number, one of {sorted(VERSIONS)}, not {cfg.version!r}")
    ver = task_version(int(cfg.version))
    cfg = replace(cfg, version=int(cfg.version), **{k: getattr(ver, k) for k in ACTION_SCALES
                                                    if getattr(cfg, k) is None})
    for name in _SWITCHES:
        if not isinstance(getattr(cfg, name), bool | np.bool_):
            raise ConfigError(f"{name} must be True or False, not {getattr(cfg, name)!r}")
    parts = cfg.target_list.split("+") if isinstance(cfg.target_list, str) else [cfg.target_list]
    if cfg.target_list is not None and (not set(parts) <= set(TARGET_LISTS) or len(set(parts)) != len(parts)):
        raise ConfigError(f"unknown target_list {cfg.target_list!r}; valid: 'A', 'B', 'F' (FE's free-space "
                          "targets), several joined by '+' (e.g. 'A+F'), or None")
    if isinstance(cfg.max_steps, bool) or not isinstance(cfg.max_steps, int | np.integer) or cfg.max_steps < 1:
        raise ConfigError(f"max_steps must be a whole number >= 1, not {cfg.max_steps!r}")
    for name in ("control_period_s", "cable_mm_per_unit", "insertion_mm_per_unit", "force_ref_n"):
        _finite(name, getattr(cfg, name), 0.0, strict=True)
    _finite("force_penalty", cfg.force_penalty, 0.0, strict=False)
    _finite("distance_weight", cfg.distance_weight, 0.0, strict=False)
    _finite("success_mm", cfg.success_mm, 0.0, strict=True)
    if cfg.timestep_s is not None:
        _finite("timestep_s", cfg.timestep_s, 0.0, strict=True)
        if cfg.timestep_s > MAX_TIMESTEP_S:
            raise ConfigError(f"timestep_s must be at most {MAX_TIMESTEP_S} s, not {cfg.timestep_s}")
    if cfg.contact_time_constant_s is not None:
        _finite("contact_time_constant_s", cfg.contact_time_constant_s, 0.0, strict=True)
        if cfg.contact_time_constant_s > 1.0:
            raise ConfigError(f"contact_time_constant_s is in seconds: at most 1, not {cfg.contact_time_constant_s}")
    cfg = replace(cfg, randomization=_randomization(cfg.randomization))
    for dt in (cfg.randomization and cfg.randomization.physics_step_s) or ():
        substeps(replace(cfg, timestep_s=dt))  # every drawn step must divide the control period
    if cfg.anatomy is not None:
        _anatomy(cfg)
    cfg = replace(cfg, **{k: bool(getattr(cfg, k)) for k in _SWITCHES}, max_steps=int(cfg.max_steps))
    if cfg.residual and cfg.task_space:
        raise ConfigError("residual and task_space each give the action another meaning (a correction of the "
                          "baseline's joint commands, a tip displacement): choose one")
    substeps(cfg)
    return cfg


ACTION_SCALES = ("control_period_s", "cable_mm_per_unit", "insertion_mm_per_unit")
# TaskConfig's on/off fields (numpy's bools accepted, stored as Python's).
_SWITCHES = ("force_obs", "force_off", "scope_obs", "time_obs", "phase_obs", "step_obs", "depth_obs", "normal_obs",
             "plan_obs", "residual", "task_space", "history_obs", "randomize_phase")


def _anatomy(cfg: TaskConfig) -> None:
    """A ConfigError unless ``cfg.anatomy`` names a stomach a task can run in."""
    a = cfg.anatomy
    if isinstance(a, bool) or not isinstance(a, int | np.integer | str):
        raise ConfigError(f"anatomy must be None (the built-in stomach), a seed (a whole number >= 0), a set "
                          f"({', '.join(ANATOMY_SETS)}, or seeds as '110-119'), or the folder of a stomach you built, "
                          f"not {a!r}")
    if isinstance(a, int | np.integer) and a < 0:
        raise ConfigError(f"anatomy seed must be >= 0, not {a}")
    if isinstance(a, str) and anatomy_set(a) is None and not (Path(a) / "stomach.json").exists():
        raise ConfigError(f"anatomy {a!r} holds no stomach.json; build one with `python -m mjendo.anatomy build "
                          f"--surface YOUR.stl --entry X Y Z --axis DX DY DZ --out {a}`")
    if cfg.version < 1:
        raise ConfigError("other anatomies exist from task version 1 (their targets are points of a map)")


def _randomization(value) -> Randomization | None:
    """TaskConfig.randomization from None/False, True (default ranges), a dict of fields or a Randomization."""
    if value is None or value is False:
        return None
    if value is True:
        return Randomization().check()
    if isinstance(value, Randomization):
        return value.check()
    if isinstance(value, dict):
        known = {f.name for f in fields(Randomization)}
        unknown = sorted(set(value) - known)
        if unknown:
            raise ConfigError(f"unknown randomization field(s) {', '.join(unknown)}; valid: {', '.join(sorted(known))}")
        return Randomization(**{k: tuple(v) if isinstance(v, list) else v for k, v in value.items()}).check()
    raise ConfigError(f"randomization must be None, True, a dict of Randomization fields or a Randomization, "
                      f"not {value!r}")


def substeps(cfg: TaskConfig) -> int:
    """Physics steps per control step (at the task's own timestep_s, else its stomach's); the period must be a
    whole number of them."""
    dt = cfg.timestep_s or fidelity_preset(cfg.fidelity, cfg.version).timestep_s
    n = round(cfg.control_period_s / dt)
    if n < 1 or abs(n * dt - cfg.control_period_s) > 1e-9:
        raise ConfigError(f"control_period_s {cfg.control_period_s} is not a multiple of the {cfg.fidelity} "
                          f"timestep {dt} s; use e.g. {max(1, n) * dt:g}")
    return n


# --------------------------------------------------------------------------
# Paper's results (Tables I and II): success rate % and average error mm.
# The evaluation report prints ours next to these, cell by cell.
PAPER_RESULTS: dict[str, dict[str, tuple[float, float]]] = {
    "A": {"FE": (98.3, 0.4), "SE": (26.2, 2.5), "DE": (34.5, 2.2), "UE1": (32.5, 2.2), "UE2": (33.8, 2.5)},
    "B": {"SE": (98.0, 1.6), "DE": (81.5, 1.7), "UE1": (75.6, 1.8), "UE2": (68.8, 2.1)},
    "C": {"SE": (100.0, 1.6), "DE": (100.0, 1.6), "UE1": (81.0, 1.9), "UE2": (78.0, 1.8)},
    "D": {"SE": (91.8, 1.6), "DE": (97.8, 1.6), "UE1": (71.3, 2.1), "UE2": (55.0, 2.0)},
    "E": {"SE": (100.0, 1.6), "DE": (100.0, 1.6), "UE1": (84.5, 1.9), "UE2": (85.0, 1.9)},
}
