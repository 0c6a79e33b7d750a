"""Assemble the MuJoCo scenes and write them under models/scenes/: one per fidelity, plus FE.

The stomach conditions SE, DE, UE1 and UE2 share one scene per fidelity
(``stomach_fast.xml``, ``stomach_full.xml``): they differ only in the
periodic load's amplitude, which the Simulator sets from the condition.
FE (no stomach) has its own ``FE.xml``. ``python -m mjendo.scene``
regenerates every committed scene file from the committed stomach mesh
and the config; ``scene_xml`` returns one as text.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
from pathlib import Path

import mujoco
import numpy as np

from mjendo import anatomy, endoscope, paths
from mjendo.config import (
    CURRENT_VERSION,
    FIDELITIES,
    MAX_TIMESTEP_S,
    PAPER_SUCCESS_MM,
    VERSIONS,
    ConfigError,
    Fidelity,
    SceneConfig,
    scene_config,
)
from mjendo.units import from_mm, to_mm

SCENES_DIR = paths.SCENES_DIR
FLEX = "stomach"
LOAD = "periodic_load"
LOAD_GAINS = "periodic_load_gains"  # custom numeric: Fidelity.load_gains
TARGET_BODY = "target"
STOMACH_GEOM_GROUP = 2
BACKDROP_GROUP = 3  # the picture's backdrop: shown by the external camera, not by the scope's


def scene_name(cfg: SceneConfig) -> str:
    return f"stomach_{cfg.fidelity.name}" if cfg.has_stomach else "FE"


def scene_path(env: str, fidelity: str = "fast", version: int = CURRENT_VERSION,
               stomach: Path | None = None) -> Path:
    """Scene file an environment runs in (FE has no stomach: one file for every fidelity).

    The built-in stomach's are committed: the current task version's in models/scenes/, other versions' in
    models/scenes/v<N>/ unless built from the same config as the current version's (one file, not two copies).
    Another stomach's (``stomach``: its folder) are built once into the cache, named by a hash of its mesh and
    sets, the task version and this module's builder.
    """
    cfg = scene_config(env, fidelity, version)
    name = f"{scene_name(cfg)}.xml"
    if stomach is None or Path(stomach).resolve() == anatomy.STOMACH_DIR.resolve():
        same = version == CURRENT_VERSION or cfg == scene_config(env, fidelity, CURRENT_VERSION)
        return (SCENES_DIR if same else SCENES_DIR / f"v{version}") / name
    stomach = Path(stomach)
    h = hashlib.sha256(f"{version} {mujoco.__version__}".encode())
    for part in ("stomach.json", "stomach.msh"):
        h.update((stomach / part).read_bytes())
    h.update(Path(__file__).read_bytes())
    path = paths.CACHE / "scenes" / h.hexdigest()[:16] / name
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        spec = build_spec(cfg, anatomy.load(stomach), stomach)
        probe(spec.compile(), fidelity=cfg.fidelity.name)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_text(spec.to_xml())
        tmp.replace(path)  # whole or not at all: parallel builders may race
    return path


def fingerprint(fidelity: str = "fast", version: int = CURRENT_VERSION) -> str:
    """Short hash of the scene files a fidelity's environments run in: results cached on disk name their model."""
    h = hashlib.sha256()
    for env in ("FE", "DE"):
        # The Jacobian's storage (dense or sparse) changes the speed, not the physics: not part of the hash.
        h.update(re.sub(rb' jacobian="\w+"', b"", scene_path(env, fidelity, version).read_bytes()))
    return h.hexdigest()[:12]


def _header(cfg: SceneConfig) -> str:
    fid = cfg.fidelity
    g = cfg.gravity * np.asarray(cfg.gravity_direction, float) / np.linalg.norm(cfg.gravity_direction)
    return f"""<mujoco model="mjendo {scene_name(cfg)}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{fid.timestep_s}" integrator="discrete" solver="{fid.solver}" jacobian="{fid.jacobian}"
          iterations="{fid.iterations}"
          tolerance="{fid.tolerance:g}" gravity="{' '.join(f'{x:.6g}' for x in g + 0.0)}" cone="pyramidal"/>
  <size memory="64M"/>
  <visual>
    <global offwidth="1280" offheight="960" azimuth="90" elevation="-10"/>
    <map force="0.02" znear="0.001" zfar="5"/>
    <scale forcewidth="0.006" contactwidth="0.004" contactheight="0.001" framelength="0.02"
           framewidth="0.002"/>
    <rgba contactforce="0.1 0.4 1 1"/>
    <headlight ambient="0.5 0.5 0.5" diffuse="0.5 0.5 0.5"/>
  </visual>
  <worldbody>
    <light pos="0 -0.6 0.4" dir="0 1 -0.6" diffuse="0.6 0.6 0.6"/>
    <camera name="external" pos="0.025 -0.31 -0.085" xyaxes="1 0 0 0 0 1" fovy="45"/>
    <!-- Visual-only backdrop behind the stomach, for contrast in pictures and videos. -->
    <geom name="backdrop" type="plane" size="0.5 0.5 0.01" pos="0.025 0.25 -0.085" zaxis="0 -1 0"
          rgba="0.16 0.18 0.22 1" contype="0" conaffinity="0" group="{BACKDROP_GROUP}"/>
  </worldbody>
</mujoco>"""


def _flexcomp(cfg: SceneConfig, st: anatomy.Stomach, msh: Path) -> str:
    fid, mat, con = cfg.fidelity, cfg.material, cfg.contact
    volume = float(np.sum(st.mesh.volumes()))
    cells = " ".join(str(c) for c in fid.cellcount)
    dof = f'dof="trilinear" cellcount="{cells}"' if fid.dof == "trilinear" else 'dof="full"'
    # Per-vertex dofs: pin the fixed vertices exactly. Interpolated dofs have
    # no vertex bodies (pins would name grid nodes): tendon equalities instead.
    pin = f'<pin id="{" ".join(map(str, st.fixed))}"/>' if fid.dof == "full" else ""
    return f"""<mujoco><worldbody>
  <flexcomp name="{FLEX}" type="gmsh" file="{msh}" dim="3" {dof} radius="0.0005"
            mass="{volume * mat.density_kg_m3:.6g}" rgba="0.85 0.45 0.45 0.35" group="{STOMACH_GEOM_GROUP}">
    {pin}
    <elasticity young="{cfg.young_pa():g}" poisson="{mat.poisson:g}" damping="{mat.damping:g}"/>
    <contact margin="{from_mm(con.margin_mm):g}" gap="{from_mm(con.gap_mm):g}"
             friction="{con.friction:g} 0.005 0.0001" contype="2" conaffinity="1" selfcollide="none"
             solimp="{' '.join(f'{x:g}' for x in (fid.contact_solimp or con.solimp))}" condim="3"/>
  </flexcomp>
</worldbody></mujoco>"""


# The constraint solvers a scene may use, by name (PGS does not run MuJoCo's discrete integrator with flex).
SOLVERS = {"CG": mujoco.mjtSolver.mjSOL_CG, "Newton": mujoco.mjtSolver.mjSOL_NEWTON}


def solver_id(name: str) -> mujoco.mjtSolver:
    """MuJoCo's id of a solver named in a fidelity or a batch, or an error naming the valid ones."""
    if name not in SOLVERS:
        raise ConfigError(f"unknown solver {name!r}; valid: {', '.join(SOLVERS)} (PGS does not run MuJoCo's "
                          "discrete integrator with flex)")
    return SOLVERS[name]


def validate(cfg: SceneConfig) -> None:
    """Reject physics parameters that are known to be unusable, naming the fix."""
    mat, fid = cfg.material, cfg.fidelity
    if mat.young_pa <= 0 or fid.young_scale <= 0:
        raise ConfigError(f"young's modulus must be positive (got {mat.young_pa} Pa)")
    if not 0.0 <= mat.poisson < 0.49:
        raise ConfigError(f"poisson ratio must be in [0, 0.49) (got {mat.poisson}); "
                          "MuJoCo's flex is ill-conditioned near incompressibility")
    if mat.damping < 0 or mat.drag_per_s < 0 or mat.density_kg_m3 <= 0:
        raise ConfigError("damping and drag_per_s must be >= 0 and density > 0")
    if not 0.0 < fid.timestep_s <= MAX_TIMESTEP_S:
        raise ConfigError(f"timestep must be in (0, {MAX_TIMESTEP_S * 1000:g} ms] (got {fid.timestep_s} s)")
    solver_id(fid.solver)


# A stomach sagging more than this under gravity has collapsed: too soft to use.
MAX_SETTLE_SAG_M = 0.03


def probe(model: mujoco.MjModel, settle_s: float = 0.5, fidelity: str = "this fidelity") -> None:
    """Settle the stomach briefly; reject parameters that make the physics unusable.

    MuJoCo's discrete integrator does not blow up on stiff flexes: too stiff a
    wall for the timestep shows as an under-converged (ill-conditioned) solve,
    too soft a wall as a stomach that collapses under gravity (settled without
    contact), a wall in the scope's way as one the retracting scope strikes.
    """
    sag = _settle(model, settle_s, contact=True)
    if np.isfinite(sag) and sag <= MAX_SETTLE_SAG_M:
        return
    if not _settle(model, settle_s, contact=False) <= MAX_SETTLE_SAG_M:  # only a failure settles twice
        raise ConfigError(f"the stomach collapses under gravity (wall moved {float(to_mm(sag)):.0f} mm while "
                          "settling): raise young or lower the density")
    raise ConfigError(f"the wall moved {float(to_mm(sag)):.0f} mm while settling, struck by the scope as it "
                      f"retracts to its shallowest insertion: at {fidelity} the wall lies in the scope's path at "
                      "the cardia; use a finer fidelity (coarse to fine: fast-coarse, fast, full) or move the "
                      "stomach's entry")


def _settle(model: mujoco.MjModel, settle_s: float, contact: bool) -> float:
    """Largest wall displacement (m) after settle_s with the scope retracted, raising on diverged physics."""
    saved = model.opt.disableflags
    if not contact:
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    try:
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        x0 = data.flexvert_xpos.copy()
        ins = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, endoscope.INSERTION)
        data.ctrl[ins] = model.actuator_ctrlrange[ins, 0]  # scope out of the way
        for _ in range(int(round(settle_s / model.opt.timestep))):
            mujoco.mj_step(model, data)
    finally:
        model.opt.disableflags = saved
    w = mujoco.mjtWarning
    if any(data.warning[k].number for k in (w.mjWARN_BADQACC, w.mjWARN_BADQVEL, w.mjWARN_BADQPOS)):
        raise ConfigError("the physics diverged while settling: lower the timestep or the stiffness")
    if data.warning[w.mjWARN_INERTIA].number:
        raise ConfigError("the stomach is too stiff for this timestep (MuJoCo's M + hD + h^2 K solve is "
                          "ill-conditioned): lower young or the timestep, or raise the fidelity's iterations")
    return np.abs(data.flexvert_xpos - x0).max() if len(x0) else 0.0


def flex_joints(model: mujoco.MjModel, flex_id: int) -> np.ndarray:
    """Joint ids of the flex's degrees of freedom (slides of its vertex or node bodies), in order."""
    bodies = {model.flex_vertbodyid[model.flex_vertadr[flex_id] + i] for i in range(model.flex_vertnum[flex_id])}
    bodies |= {model.flex_nodebodyid[model.flex_nodeadr[flex_id] + i] for i in range(model.flex_nodenum[flex_id])}
    bodies.discard(-1)
    bodies.discard(0)
    return np.array(sorted(j for j in range(model.njnt) if model.jnt_bodyid[j] in bodies), dtype=np.int64)


def vertex_jacobian(model: mujoco.MjModel, flex_id: int, vertices: list[int],
                     dofs: np.ndarray) -> np.ndarray:
    """d(vertex positions)/d(qpos of the flex dofs): (len(vertices), 3, len(dofs)).

    The map is linear (vertex = interpolation of node slides), so a unit
    finite difference is exact; it covers full and interpolated dofs alike.
    """
    data = mujoco.MjData(model)
    h = 1e-3  # any step is exact for a linear map
    adr = model.flex_vertadr[flex_id]
    mujoco.mj_kinematics(model, data)
    mujoco.mj_flex(model, data)
    x0 = data.flexvert_xpos[adr + np.asarray(vertices)].copy()
    jac = np.zeros((len(vertices), 3, len(dofs)))
    for k, q in enumerate(dofs):
        data.qpos[q] += h
        mujoco.mj_kinematics(model, data)
        mujoco.mj_flex(model, data)
        jac[:, :, k] = (data.flexvert_xpos[adr + np.asarray(vertices)] - x0) / h
        data.qpos[q] -= h
    return jac


def build_spec(cfg: SceneConfig, stomach: anatomy.Stomach | None = None,
               stomach_dir: Path = anatomy.STOMACH_DIR) -> mujoco.MjSpec:
    """The complete scene as an MjSpec (compiled once to resolve the flex)."""
    validate(cfg)
    st = stomach or anatomy.load(stomach_dir)
    spec = mujoco.MjSpec.from_string(_header(cfg))
    if cfg.has_stomach:
        flex_spec = mujoco.MjSpec.from_string(_flexcomp(cfg, st, (stomach_dir / "stomach.msh").resolve()))
        flex_spec.compile()
        spec = _merge_flex(spec, flex_spec)
    # Target marker: a mocap body the task moves onto the target vertex.
    tgt = spec.worldbody.add_body(name=TARGET_BODY, mocap=True, pos=st.entry)
    # Marker radius = the paper's 3 mm success distance.
    tgt.add_site(name=TARGET_BODY, size=[from_mm(PAPER_SUCCESS_MM), 0, 0], rgba=[1, 1, 1, 1])
    endoscope.add_endoscope(spec, cfg.endoscope, st.entry, st.axis, cfg.contact.friction)
    model = spec.compile()
    endoscope.set_cable_rest_lengths(spec, model)
    if cfg.has_stomach:
        _add_anchors_and_load(spec, model, st, cfg)
    return spec


def _merge_flex(spec: mujoco.MjSpec, flex_spec: mujoco.MjSpec) -> mujoco.MjSpec:
    """Header + expanded flex in one spec (flexcomp expands into bodies and a <flex>)."""
    header = spec.to_xml()
    flex_xml = flex_spec.to_xml()
    # Splice the expanded flex's worldbody and deformable sections into the header.
    wb = flex_xml.split("<worldbody>", 1)[1].split("</worldbody>", 1)[0]
    deform = flex_xml.split("<deformable>", 1)[1].split("</deformable>", 1)[0]
    header = header.replace("</worldbody>", wb + "</worldbody>", 1)
    header = header.replace("</mujoco>", f"<deformable>{deform}</deformable>\n</mujoco>", 1)
    return mujoco.MjSpec.from_string(header)


def _add_anchors_and_load(spec: mujoco.MjSpec, model: mujoco.MjModel,
                          st: anatomy.Stomach, cfg: SceneConfig) -> None:
    """Fixed vertices (tendon equalities), the periodic load (tendon motor) and the wall's drag.

    Anchors and load are fixed tendons whose coefficients map flex dofs to a vertex's
    displacement, so the same mechanism works for per-vertex and
    interpolated (trilinear) dofs.
    """
    flex_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, FLEX)
    dofs = flex_joints(model, flex_id)
    joints = spec.joints  # a fresh list of every joint per access: read it once
    for j in dofs:
        body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, model.jnt_bodyid[j])
        axis = "xyz"[int(np.argmax(np.abs(model.jnt_axis[j])))]
        joints[j].name = f"{body}_{axis}"
    names = [joints[j].name for j in dofs]
    # Rayleigh alpha, damping proportional to each flex dof's mass, as the damping of a passive
    # actuator per dof (no gain, so ctrl does nothing): MuJoCo refuses joint damping on flex bodies.
    # The elastic foundation (Material.foundation_per_s2) is the same actuator's spring to the rest position.
    mat = cfg.material
    for j, name in zip(dofs, names, strict=True) if mat.drag_per_s > 0 or mat.foundation_per_s2 > 0 else ():
        a = spec.add_actuator(name=f"drag_{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.gainprm[0] = 0.0
        mass = model.body_mass[model.jnt_bodyid[j]]
        a.damping = [mat.drag_per_s * mass, 0, 0]
        if mat.foundation_per_s2 > 0:
            a.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            a.biasprm[1] = -mat.foundation_per_s2 * mass
    anchored = [] if cfg.fidelity.dof == "full" else st.fixed  # full: pinned in the flexcomp
    jac = vertex_jacobian(model, flex_id, anchored + st.forced, model.jnt_qposadr[dofs])
    for k, v in enumerate(anchored):
        for a, axis in enumerate("xyz"):
            t = spec.add_tendon(name=f"anchor{v}_{axis}")
            for name, coef in zip(names, jac[k, a], strict=False):
                if abs(coef) > 1e-9:
                    t.wrap_joint(name, float(coef))
            spec.add_equality(type=mujoco.mjtEq.mjEQ_TENDON, name1=t.name,
                              solref=[0.01, 1.0], solimp=[0.99, 0.999, 0.001, 0.5, 2])
    direction = np.asarray(cfg.load.direction, float)
    coefs = np.einsum("vaj,a->j", jac[len(anchored):], direction / np.linalg.norm(direction))
    t = spec.add_tendon(name=LOAD)
    for name, coef in zip(names, coefs, strict=False):
        if abs(coef) > 1e-9:
            t.wrap_joint(name, float(coef))
    a = spec.add_actuator(name=LOAD, target=LOAD, trntype=mujoco.mjtTrn.mjTRN_TENDON)
    # The calibrated gains travel in the scene file; the Simulator scales its square wave by them.
    spec.add_numeric(name=LOAD_GAINS, data=list(cfg.fidelity.load_gains))
    a.ctrlrange = [-10.0 * max(cfg.fidelity.load_gains), 10.0 * max(cfg.fidelity.load_gains)]
    a.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE


def scene_xml(env: str, fidelity: str | Fidelity = "fast", check: bool = True, version: int = CURRENT_VERSION,
              **overrides) -> str:
    """The scene file's text for an environment, fidelity and task version, probed for usable physics."""
    cfg = scene_config(env, fidelity, version, **overrides)
    spec = build_spec(cfg)
    if check:
        probe(spec.compile(), fidelity=cfg.fidelity.name)
    return spec.to_xml()


def write_all(directory: Path = SCENES_DIR) -> list[Path]:
    """Every committed scene: each task version's FE and stomach scenes at each fidelity."""
    written = []
    for version in VERSIONS:
        for env, fid in [("FE", "fast")] + [("SE", f) for f in FIDELITIES if FIDELITIES[f].first_version <= version]:
            path = directory / scene_path(env, fid, version).relative_to(SCENES_DIR)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(scene_xml(env, fid, version=version))
            written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.scene", description=__doc__)
    ap.add_argument("--out", type=Path, default=SCENES_DIR)
    args = ap.parse_args(argv)
    for p in write_all(args.out):
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
