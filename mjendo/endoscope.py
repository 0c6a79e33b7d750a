"""The flexible robotic endoscope as MuJoCo bodies, cables and actuators.

A carriage on a slide joint (insertion through the cardia) carries a chain of
capsule links: a passive insertion tube, then the 79 mm active segment. Every
link joint is a pair of hinges (two bending planes) whose stiffness is the
tube's bending stiffness EI divided by the link length. Four cables are
spatial tendons through sites at +-r on the active links, pulled by
pull-only servo actuators whose control is the cable displacement (metres,
positive pulls, negative pays out slack).
"""

from __future__ import annotations

import mujoco
import numpy as np

from mjendo.config import Endoscope
from mjendo.units import from_mm

CABLES = ("cable_px", "cable_nx", "cable_py", "cable_ny")  # +x, -x, +y, -y side
INSERTION = "insertion"
TIP_SITE = "ee"
TIP_BODY = "tip"
TIP_LIGHT = "tip_light"
TIP_CAMERA = "tip_camera"
LINK_PREFIX = "link"
CARRIAGE = "carriage"
PIVOT = "cardia_pivot"
HIATUS_BAR_RADIUS = 0.002  # m
HIATUS_CONTYPE = 4  # with conaffinity 1: touches the scope (contype 1), not the stomach (contype 2, conaffinity 1)


def quat_z_to(direction: np.ndarray) -> np.ndarray:
    """Quaternion rotating +z onto ``direction``."""
    z = np.array([0.0, 0.0, 1.0])
    d = direction / np.linalg.norm(direction)
    axis = np.cross(z, d)
    s, c = np.linalg.norm(axis), float(np.dot(z, d))
    if s < 1e-12:
        return np.array([1.0, 0, 0, 0]) if c > 0 else np.array([0.0, 1, 0, 0])
    angle = np.arctan2(s, c)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis / s])


def max_cable_pull(cfg: Endoscope) -> float:
    """Cable stroke (m) that bends the active segment to about 150 degrees."""
    return from_mm(cfg.cable_offset_mm) * np.radians(150.0) + cfg.cable_max_tension_n / cfg.cable_kp_n_per_m


def add_endoscope(spec: mujoco.MjSpec, cfg: Endoscope, entry: np.ndarray, axis: np.ndarray,
                  friction: float) -> None:
    """Add carriage, links, cables and actuators to ``spec``.

    At insertion 0 the tip is ``cfg.start_depth_mm`` past ``entry`` along
    ``axis``; the rest of the simulated tube trails back out of the cardia.
    ``friction`` is the tube's sliding friction: MuJoCo combines a contact's
    two coefficients by their maximum, so the tube must carry the wall's value
    (a default geom's 1.0 would override the paper's 0.1).
    """
    radius = from_mm(cfg.diameter_mm) / 2
    la, lp = from_mm(cfg.active_length_mm), from_mm(cfg.passive_length_mm)
    l_act, l_pas = la / cfg.n_active_links, lp / cfg.n_passive_links
    behind = (from_mm(cfg.start_depth_mm) - la - lp) * np.array([0.0, 0.0, 1.0])  # carriage in the pivot frame
    # Geom density that gives the tube its linear density.
    density = cfg.linear_density_kg_m / (np.pi * radius**2)

    if cfg.pivot_stiffness_Nm_per_rad is None:  # rigid straight slide
        carriage = spec.worldbody.add_body(name=CARRIAGE, pos=entry + behind[2] * axis, quat=quat_z_to(axis))
    else:  # the slide hangs in a compliant pivot at the cardia
        pivot = spec.worldbody.add_body(name=PIVOT, pos=entry, quat=quat_z_to(axis))
        lim = np.radians(cfg.pivot_range_deg)
        for ax, tag in (([1, 0, 0], "x"), ([0, 1, 0], "y")):
            pivot.add_joint(name=f"{PIVOT}_{tag}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=ax,
                            stiffness=cfg.pivot_stiffness_Nm_per_rad, damping=cfg.pivot_damping,
                            armature=cfg.joint_armature, range=[-lim, lim], limited=mujoco.mjtLimited.mjLIMITED_TRUE)
        # The hiatus: a ring of short capsules around the tube, on the pivot, through which the tube slides.
        ring_r, bar_r, n_bars = radius + from_mm(cfg.hiatus_clearance_mm) + HIATUS_BAR_RADIUS, HIATUS_BAR_RADIUS, 8
        half = ring_r * np.tan(np.pi / n_bars)
        for k in range(n_bars):
            a = 2 * np.pi * k / n_bars
            c, t = ring_r * np.array([np.cos(a), np.sin(a), 0.0]), np.array([-np.sin(a), np.cos(a), 0.0])
            pivot.add_geom(name=f"hiatus{k}", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                           fromto=[*(c - half * t), *(c + half * t)], size=[bar_r, 0, 0], mass=0.01 / n_bars,
                           contype=HIATUS_CONTYPE, conaffinity=1, condim=3,
                           friction=[friction, 0.005, 0.0001], group=3, rgba=[0.8, 0.5, 0.5, 1])
        carriage = pivot.add_body(name=CARRIAGE, pos=behind)
    carriage.add_joint(name=INSERTION, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 0, 1],
                       range=from_mm(cfg.insertion_range_mm), limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                       damping=cfg.insertion_damping, armature=0.05)
    carriage.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], contype=0,
                      conaffinity=0, group=3, mass=0.05)

    lengths = [l_pas] * cfg.n_passive_links + [l_act] * cfg.n_active_links
    parent = carriage
    pos = np.zeros(3)
    r = from_mm(cfg.cable_offset_mm)
    cable_sites: dict[str, list[str]] = {c: [] for c in CABLES}
    offsets = {"cable_px": (r, 0), "cable_nx": (-r, 0), "cable_py": (0, r), "cable_ny": (0, -r)}
    for i, length in enumerate(lengths):
        active = i >= cfg.n_passive_links
        last = i == len(lengths) - 1
        name = TIP_BODY if last else f"{LINK_PREFIX}{i}"
        body = parent.add_body(name=name, pos=pos)
        ei = cfg.active_EI_Nm2 if active else cfg.passive_EI_Nm2
        for ax, tag in (([1, 0, 0], "x"), ([0, 1, 0], "y")):
            body.add_joint(name=f"bend{i}_{tag}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=ax,
                           stiffness=ei / length, damping=cfg.joint_damping,
                           armature=cfg.joint_armature)
        end = length - radius if last else length
        body.add_geom(name=f"geom_{name}", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                      fromto=[0, 0, 0, 0, 0, end], size=[radius, 0, 0], density=density,
                      contype=1, conaffinity=2, condim=3, friction=[friction, 0.005, 0.0001],
                      rgba=[0.2, 0.22, 0.28, 1] if active else [0.38, 0.4, 0.45, 1])
        # Cables run in sheaths through the passive tube: they start at the
        # base of the active segment (distal end of the last passive link).
        # Sites sit a spacer-disc gap (inset) away from each joint, so a cable
        # shortens when the segment bends towards its side and lengthens away.
        inset = 0.2 * length
        if i == cfg.n_passive_links - 1 or active:
            for c, (x, y) in offsets.items():
                if active:
                    site = body.add_site(name=f"{c}_{i}_in", pos=[x, y, inset], size=[4e-4, 0, 0], group=4)
                    cable_sites[c].append(site.name)
                site = body.add_site(name=f"{c}_{i}_out", pos=[x, y, length - inset],
                                     size=[4e-4, 0, 0], group=4)
                cable_sites[c].append(site.name)
        if last:
            body.add_site(name=TIP_SITE, pos=[0, 0, length], size=[1e-3, 0, 0], rgba=[1, 0.6, 0, 1])
            # Eye-in-hand camera looking along the tip axis (MuJoCo cameras look along -z).
            # 4 mm behind the tip face: a lens flush with the face is inside the wall whenever the tip touches it.
            body.add_camera(name=TIP_CAMERA, pos=[0, 0, length - 0.004], quat=[0, 1, 0, 0], fovy=100)
            # The endoscope's own light at its tip, as on a real scope (visual only): without it the
            # tip camera looks into a dark, back-lit lumen.
            body.add_light(name=TIP_LIGHT, pos=[0, 0, length], dir=[0, 0, 1], cutoff=70, exponent=2,
                           diffuse=[0.9, 0.85, 0.8], specular=[0.1, 0.1, 0.1], castshadow=False,
                           attenuation=[1, 0, 0])
        parent = body
        pos = np.array([0, 0, length])

    for c in CABLES:
        t = spec.add_tendon(name=c, width=3e-4, rgba=[0.9, 0.9, 0.2, 1])
        for s in cable_sites[c]:
            t.wrap_site(s)
    # Cable servo: force = kp * ((L0 - pull) - L), pull = ctrl >= 0, pull only.
    for c in CABLES:
        a = spec.add_actuator(name=c, target=c, trntype=mujoco.mjtTrn.mjTRN_TENDON)
        a.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        a.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        a.gainprm[0] = -cfg.cable_kp_n_per_m
        # biasprm[0] (kp * L0) is set after compiling, when L0 is known.
        a.biasprm[1] = -cfg.cable_kp_n_per_m
        # Negative pull pays cable out (it goes slack: the actuator cannot push).
        a.ctrlrange = [-max_cable_pull(cfg), max_cable_pull(cfg)]
        a.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        a.forcerange = [-cfg.cable_max_tension_n, 0.0]
        a.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    a = spec.add_actuator(name=INSERTION, target=INSERTION, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    a.gaintype = mujoco.mjtGain.mjGAIN_FIXED
    a.biastype = mujoco.mjtBias.mjBIAS_AFFINE
    a.gainprm[0] = cfg.insertion_kp_n_per_m
    a.biasprm[1] = -cfg.insertion_kp_n_per_m
    a.ctrlrange = from_mm(cfg.insertion_range_mm)
    a.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    a.forcerange = [-cfg.insertion_max_force_n, cfg.insertion_max_force_n]
    a.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE


def set_cable_rest_lengths(spec: mujoco.MjSpec, model: mujoco.MjModel) -> None:
    """Zero pull holds each cable at its straight-tube length."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for c in CABLES:
        length = data.ten_length[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, c)]
        spec.actuator(c).biasprm[0] = spec.actuator(c).biasprm[1] * -length
