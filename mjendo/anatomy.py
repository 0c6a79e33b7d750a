"""The stomach: a J-shaped lumen surface, its wall mesh, landmarks and vertex sets.

Build the committed model with ``python -m mjendo.anatomy build``; bring your
own lumen surface (closed, outward-oriented .stl/.obj/.ply in millimetres)
with ``--surface FILE --entry X Y Z --axis DX DY DZ``; print sizes and mesh
quality with ``python -m mjendo.anatomy report``.

Frame (metres): z up, the J lies in the x-z plane, the body descends along
-z at x = 0 and the antrum rises towards +x (the lesser curvature faces +x).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from mjendo import cli, paths, tetmesh
from mjendo.config import (
    PAPER_N_FIXED,
    PAPER_N_FORCED,
    AnatomyRanges,
    ConfigError,
    Endoscope,
    StomachShape,
    anatomy_set,
)
from mjendo.tetmesh import GMSH_ALGORITHMS, MeshError, TetMesh, extrude_wall, gmsh_wall, quality
from mjendo.units import from_mm, to_mm

STOMACH_DIR = paths.STOMACH_DIR


@dataclass
class Stomach:
    """Wall mesh plus everything the scene and the task need to know about it."""

    mesh: TetMesh
    entry: np.ndarray  # cardia centre on the lumen, metres
    axis: np.ndarray  # unit insertion direction into the lumen
    fixed: list[int]  # anchored vertices (paper: 3)
    forced: list[int]  # periodically loaded vertices (paper: 2)
    targets_a: list[int]  # training targets, lumen vertices
    targets_b: list[int]  # held-out targets, disjoint from A
    info: dict  # sizes and quality, for reports


# --------------------------------------------------------------------------
# Built-in lumen: a tube of varying radius swept along a J-shaped centreline.

def _centreline(shape: StomachShape, ds: float = 2e-4):
    """Dense samples of (s, point, normal-towards-lesser-curvature, radius)."""
    rf, rb = from_mm(shape.fundus_radius_mm), from_mm(shape.body_radius_mm)
    lb, rbend = from_mm(shape.body_length_mm), from_mm(shape.bend_radius_mm)
    phi = np.radians(shape.bend_angle_deg)
    ra, la, rp = from_mm(shape.antrum_radius_mm), from_mm(shape.antrum_length_mm), \
        from_mm(shape.pylorus_radius_mm)
    s1, s2 = rf, rf + lb
    s3 = s2 + rbend * phi
    s4 = s3 + la
    total = s4 + rp
    s = np.arange(0.0, total + ds / 2, ds)
    s[-1] = total
    alpha = np.clip((s - s2) / rbend, 0.0, phi)  # tangent angle
    # Integrate the tangent t = (sin a, 0, -cos a) for positions.
    t = np.stack([np.sin(alpha), np.zeros_like(s), -np.cos(alpha)], 1)
    pts = np.concatenate([[np.zeros(3)], np.cumsum(0.5 * (t[1:] + t[:-1]) * np.diff(s)[:, None], 0)])
    nrm = np.stack([np.cos(alpha), np.zeros_like(s), np.sin(alpha)], 1)

    def smooth(u):  # 0..1 cosine ramp
        u = np.clip(u, 0.0, 1.0)
        return 0.5 - 0.5 * np.cos(np.pi * u)

    r = np.where(s < s1, np.sqrt(np.clip(rf**2 - (rf - s) ** 2, 0, None)), rb)
    r = np.where(s >= s2, rb + (ra - rb) * smooth((s - s2) / (s3 - s2)), r)
    r = np.where(s >= s3, ra + (rp - ra) * smooth((s - s3) / la), r)
    r = np.where(s >= s4, np.sqrt(np.clip(rp**2 - (s - s4) ** 2, 0, None)), r)
    return s, pts, nrm, r


def lumen_surface(shape: StomachShape) -> tuple[np.ndarray, np.ndarray, dict]:
    """Closed, outward-oriented triangle surface of the lumen, plus landmarks."""
    if shape.n_around < 6 or shape.n_around % 2:
        raise MeshError("n_around must be an even number >= 6 (both curvatures need a meridian)")
    s, pts, nrm, r = _centreline(shape)
    # Place rings at equal steps of the meridian length of the profile (s, r),
    # so the domes get rings as densely as the tube.
    meridian = np.concatenate([[0], np.cumsum(np.hypot(np.diff(s), np.diff(r)))])
    n_rings = max(3, int(round(meridian[-1] / from_mm(shape.ring_spacing_mm))) - 1)
    targets = np.linspace(0, meridian[-1], n_rings + 2)[1:-1]
    idx = np.searchsorted(meridian, targets)
    binorm = np.array([0.0, 1.0, 0.0])
    theta = 2 * np.pi * np.arange(shape.n_around) / shape.n_around
    ring_pts = (pts[idx][:, None, :]
                + r[idx][:, None, None] * (np.cos(theta)[None, :, None] * nrm[idx][:, None, :]
                                           + np.sin(theta)[None, :, None] * binorm))
    verts = np.concatenate([[pts[0]], ring_pts.reshape(-1, 3), [pts[-1]]])
    k = shape.n_around

    def vid(i, j):
        return 1 + i * k + (j % k)

    faces = []
    top, bottom = 0, len(verts) - 1
    for j in range(k):
        faces.append((top, vid(0, j + 1), vid(0, j)))
        faces.append((bottom, vid(n_rings - 1, j), vid(n_rings - 1, j + 1)))
    for i in range(n_rings - 1):
        for j in range(k):
            a, b, c, d = vid(i, j), vid(i, j + 1), vid(i + 1, j + 1), vid(i + 1, j)
            faces += [(a, b, c), (a, c, d)]
    faces = np.asarray(faces, np.int64)
    # Orientation: the winding above follows the sweep; flip if it points inwards.
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    if np.einsum("ij,ij->", a, np.cross(b, c)) < 0:
        faces = faces[:, ::-1].copy()
    # Cardia on the lesser-curvature meridian (theta = 0) of the ring nearest
    # the given arclength; the insertion axis aims at the body's centreline.
    ring_s = s[idx]
    ic = int(np.argmin(np.abs(ring_s - from_mm(shape.cardia_arclength_mm))))
    entry = ring_pts[ic, 0]
    aim = pts[np.searchsorted(s, ring_s[ic] + from_mm(70.0))]
    axis = (aim - entry) / np.linalg.norm(aim - entry)
    landmarks = {
        "ring_index": idx, "n_rings": n_rings, "cardia_ring": ic,
        "entry": entry, "axis": axis,
        # Meridian vertex ids (lumen surface) for curvature lengths.
        "lesser_meridian": [vid(i, 0) for i in range(n_rings)],
        "greater_meridian": [vid(i, k // 2) for i in range(n_rings)],
        "top": top, "bottom": bottom,
    }
    return verts, faces, landmarks


def _polyline_length(p: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


def measure(points: np.ndarray) -> dict:
    """Outer length of the organ: extent along its principal axis, mm."""
    c = points - points.mean(0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    proj = c @ vt.T
    ext = to_mm(proj.max(0) - proj.min(0))
    return {"length_mm": float(ext[0]), "width_mm": float(ext[1]), "depth_mm": float(ext[2])}


# --------------------------------------------------------------------------
# Vertex sets.

def free_workspace(entry: np.ndarray, axis: np.ndarray, scope: Endoscope,
                   n_depth: int = 24, n_bend: int = 14, n_dir: int = 24) -> np.ndarray:
    """Tip positions reachable in free space (constant-curvature bending, no contact)."""
    u = np.cross(axis, [0.0, 1.0, 0.0])
    if np.linalg.norm(u) < 1e-6:
        u = np.cross(axis, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    la = from_mm(scope.active_length_mm)
    lo, hi = from_mm(scope.insertion_range_mm)
    depth = from_mm(scope.start_depth_mm) + np.linspace(max(lo, 0.0), hi, n_depth)
    bend = np.linspace(1e-3, np.radians(120.0), n_bend)
    phi = np.linspace(0, 2 * np.pi, n_dir, endpoint=False)
    radial = la * (1 - np.cos(bend)) / bend
    along = la * np.sin(bend) / bend
    base = entry + (depth - la)[:, None] * axis  # active segment starts la before the tip
    d = (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    pts = (base[:, None, None, :] + along[None, :, None, None] * axis
           + radial[None, :, None, None] * d[None, None, :, :])
    return pts.reshape(-1, 3)


def choose_sets(mesh: TetMesh, entry: np.ndarray, axis: np.ndarray,
                scope: Endoscope, band_mm: float = 20.0, pylorus: np.ndarray | None = None) -> dict:
    """Fixed, forced and target vertex sets, deterministic.

    * fixed: two outer vertices at the cardia (gastro-oesophageal junction,
      held by the hiatus) and the outer vertex farthest along the antrum
      (pylorus, held by the duodenum): the one nearest ``pylorus`` (the pyloric end of a built lumen),
      or for a surface without that landmark the farthest towards +x and up;
    * forced: the two outer vertices highest on the fundus (under the
      diaphragm, which drives breathing motion);
    * targets: lumen vertices within ``band_mm`` of the free-space workspace
      (reachable with the help of contact), away from the cardia, split
      alternately (by angle around the insertion axis) into A (2/3) and B.
    """
    p, inner = mesh.points, mesh.inner
    outer_ids = np.flatnonzero(~inner)
    d_entry = np.linalg.norm(p - entry, axis=1)
    near_cardia = outer_ids[np.argsort(d_entry[outer_ids])]
    first = near_cardia[0]
    # Second cardia anchor: the nearest outer vertex on the far side of the rim.
    far_side = [i for i in near_cardia[1:12] if np.dot(p[i] - entry, p[first] - entry) < 0]
    second = far_side[0] if far_side else near_cardia[1]
    end = outer_ids[np.argmax(p[outer_ids] @ np.array([1.0, 0.0, 0.3]))] if pylorus is None \
        else outer_ids[np.argmin(np.linalg.norm(p[outer_ids] - pylorus, axis=1))]
    fixed = [int(first), int(second), int(end)]
    forced = [int(i) for i in outer_ids[np.argsort(-p[outer_ids, 2])][:PAPER_N_FORCED]]
    assert len(fixed) == PAPER_N_FIXED

    ws = free_workspace(entry, axis, scope)
    lumen = np.flatnonzero(inner)
    dist = np.array([np.min(np.linalg.norm(ws - p[i], axis=1)) for i in lumen])
    ok = (dist < from_mm(band_mm)) & (d_entry[lumen] > from_mm(35.0))
    targets_a, targets_b = split_targets(p, entry, axis, lumen[ok])
    free = {int(i) for i, d in zip(lumen, dist, strict=False) if d < from_mm(3.0)}
    return {"fixed": fixed, "forced": forced, "targets_a": targets_a,
            "targets_b": targets_b, "free_reachable": sorted(free & set(targets_a + targets_b))}


def split_targets(points: np.ndarray, entry: np.ndarray, axis: np.ndarray,
                  candidates, pattern: str = "AAB") -> tuple[list[int], list[int]]:
    """Lists A (training) and B (held out): ordered around the insertion axis, then dealt by ``pattern``.

    "AAB" gives A 2/3 and B 1/3. Interleaving keeps both lists over the same regions of the wall.
    """
    cand = np.asarray(candidates, dtype=np.int64)
    u = np.cross(axis, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    rel = points[cand] - entry
    order = cand[np.lexsort((rel @ axis, np.round(np.arctan2(rel @ v, rel @ u), 3)))]
    deal = [pattern[n % len(pattern)] for n in range(len(order))]
    return ([int(i) for i, d in zip(order, deal, strict=True) if d == "A"],
            [int(i) for i, d in zip(order, deal, strict=True) if d == "B"])


# --------------------------------------------------------------------------
# Build, save, load.

def build(shape: StomachShape | None = None, scope: Endoscope | None = None) -> Stomach:
    """The built-in stomach, deterministically."""
    shape = shape or StomachShape()
    scope = scope or Endoscope()
    verts, faces, lm = lumen_surface(shape)
    mesh = tetmesh.extrude_wall(verts, faces, from_mm(shape.wall_thickness_mm),
                                lm["entry"], from_mm(shape.cardia_radius_mm), shape.wall_layers)
    info = measure(mesh.points)
    t = from_mm(shape.wall_thickness_mm)
    # Greater curvature: outer wall from the cardia over the fundus dome to
    # the pylorus (lesser meridian up to the top, then the greater meridian).
    normals = tetmesh.vertex_normals(verts, faces)
    outer = verts + t * normals
    ic = lm["cardia_ring"]
    path = np.concatenate([outer[lm["lesser_meridian"][ic::-1]], outer[[lm["top"]]],
                           outer[lm["greater_meridian"]], outer[[lm["bottom"]]]])
    info["greater_curvature_mm"] = float(to_mm(_polyline_length(path)))
    lesser = np.concatenate([outer[lm["lesser_meridian"][ic:]], outer[[lm["bottom"]]]])
    info["lesser_curvature_mm"] = float(to_mm(_polyline_length(lesser)))
    info["wall_thickness_mm"] = shape.wall_thickness_mm
    sets = choose_sets(mesh, lm["entry"], lm["axis"], scope, pylorus=verts[lm["bottom"]])
    info.update(tetmesh.quality(mesh))
    info["free_reachable_targets"] = sets.pop("free_reachable")
    # Geometric candidates; `python -m mjendo.targets` keeps those reached in simulation.
    info["candidates"] = sorted(sets["targets_a"] + sets["targets_b"])
    return Stomach(mesh, lm["entry"], lm["axis"], info=info, **sets)


def sample_shape(seed: int, ranges: AnatomyRanges | None = None) -> StomachShape:
    """The shape of generated stomach ``seed``: every AnatomyRanges field drawn uniformly, deterministically."""
    ranges = ranges or AnatomyRanges()
    rng = np.random.default_rng([seed, 20261125])  # a stream of its own, not the training seeds'
    drawn = {f.name: round(float(rng.uniform(*getattr(ranges, f.name))), 2) for f in fields(AnatomyRanges)}
    return replace(StomachShape(), **drawn)


def generate(seed: int, scope: Endoscope | None = None) -> Stomach:
    """Generated stomach ``seed``: a sampled shape built like the built-in one (same wall, same rules)."""
    shape = sample_shape(seed)
    st = build(shape, scope)
    st.info["seed"] = seed
    st.info["shape"] = asdict(shape)
    return st


def anatomy_dir(seed: int) -> Path:
    """Folder of generated stomach ``seed``: the benchmark's committed one, else built once into the cache."""
    committed = paths.ANATOMIES_DIR / f"seed-{seed}"
    if (committed / "stomach.json").exists():
        return committed
    key = hashlib.sha256(json.dumps(asdict(sample_shape(seed))).encode()).hexdigest()[:10]
    cached = paths.CACHE / "anatomies" / f"seed-{seed}-{key}"
    if not (cached / "stomach.json").exists():
        save(generate(seed), cached)
    return cached


def members(anatomy: int | str | None) -> list:
    """The stomachs an environment draws its episodes from: a set's seeds, else the one given."""
    seeds = anatomy_set(anatomy)
    return [anatomy] if seeds is None else list(seeds)


def stomach_dir(anatomy: int | str | Path | None) -> Path:
    """The folder of a task's stomach: None the built-in one, a seed a generated one, a path a user's own."""
    if anatomy is None:
        return STOMACH_DIR
    if anatomy_set(anatomy) is not None:
        raise ConfigError(f"anatomy {anatomy!r} is a set of stomachs: the environment (EndoscopeEnv) draws one "
                          "per episode; a task runs in one stomach (its seed)")
    if isinstance(anatomy, int | np.integer) and not isinstance(anatomy, bool):
        return anatomy_dir(int(anatomy))
    return Path(anatomy)


def from_surface(path: Path, entry_mm, axis, thickness_mm: float = 5.0,
                 entry_radius_mm: float = 15.0, scope: Endoscope | None = None) -> Stomach:
    """A stomach from a user's closed lumen surface (millimetres)."""
    import trimesh

    path = Path(path)
    if not path.exists():
        raise MeshError(f"surface file {path} does not exist")
    try:
        tm = trimesh.load(str(path), force="mesh", process=True)
    except Exception as exc:
        raise MeshError(f"cannot read {path}: {exc}; use .stl, .obj or .ply") from exc
    verts = from_mm(np.asarray(tm.vertices))
    faces = np.asarray(tm.faces, np.int64)
    if len(faces) < 4 or not np.isfinite(verts).all():
        raise MeshError(f"{path} holds {len(faces)} triangles{'' if np.isfinite(verts).all() else ' and NaN vertices'}"
                        ": give a closed lumen surface (a watertight triangle mesh in .stl, .obj or .ply)")
    axis = np.asarray(axis, float)
    if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
        raise MeshError(f"--axis {axis.tolist()} is no direction: give the way the scope enters, e.g. 1 0 0")
    size = to_mm(verts.max(0) - verts.min(0)).max()
    if not 50.0 <= size <= 500.0:
        raise MeshError(f"surface is {size:.1f} mm across; a stomach is 100-300 mm. "
                        "Is it in millimetres? Rescale it (e.g. metres x 1000)")
    entry = from_mm(np.asarray(entry_mm, float))
    axis = axis / np.linalg.norm(axis)
    # Snap the entry onto the surface.
    entry = verts[np.argmin(np.linalg.norm(verts - entry, axis=1))]
    mesh = tetmesh.extrude_wall(verts, faces, from_mm(thickness_mm), entry,
                                from_mm(entry_radius_mm))
    info = measure(mesh.points) | tetmesh.quality(mesh)
    info["wall_thickness_mm"] = thickness_mm
    scope = scope or Endoscope()
    sets = choose_sets(mesh, entry, axis, scope)
    info["free_reachable_targets"] = sets.pop("free_reachable")
    info["candidates"] = sorted(sets["targets_a"] + sets["targets_b"])
    return Stomach(mesh, entry, axis, info=info, **sets)


def save(stomach: Stomach, directory: Path = STOMACH_DIR) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    tetmesh.write_msh(stomach.mesh, directory / "stomach.msh")
    meta = {
        "units": "metres (mesh), millimetres (info)",
        "entry": [round(float(x), 9) for x in stomach.entry],
        "axis": [round(float(x), 9) for x in stomach.axis],
        "inner": np.flatnonzero(stomach.mesh.inner).tolist(),
        "fixed": stomach.fixed, "forced": stomach.forced,
        "targets_a": stomach.targets_a, "targets_b": stomach.targets_b,
        "info": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in stomach.info.items()},
    }
    (directory / "stomach.json").write_text(json.dumps(meta, indent=1) + "\n")


def load(directory: Path = STOMACH_DIR) -> Stomach:
    """Load a saved stomach (mesh + sets), validating it."""
    directory = Path(directory)
    meta_path = directory / "stomach.json"
    if not meta_path.exists():
        raise MeshError(f"{meta_path} is missing; build it with `python -m mjendo.anatomy build`")
    meta = json.loads(meta_path.read_text())
    points, tets = tetmesh.read_msh(directory / "stomach.msh")
    inner = np.zeros(len(points), bool)
    inner[meta["inner"]] = True
    mesh = tetmesh.orient(TetMesh(points, tets, inner))
    for key in ("fixed", "forced", "targets_a", "targets_b"):
        ids = np.asarray(meta[key])
        if ids.size and (ids.min() < 0 or ids.max() >= len(points)):
            raise MeshError(f"{meta_path}: {key} names vertices outside the mesh; rebuild it")
    return Stomach(mesh, np.asarray(meta["entry"]), np.asarray(meta["axis"]), meta["fixed"],
                   meta["forced"], meta["targets_a"], meta["targets_b"], meta["info"])


def meshers_table(sizes_mm=(10.0, 6.0)) -> str:
    """Markdown table: the built-in wall by prism extrusion, and by gmsh on the same boundary and remeshed."""
    import time

    shape = StomachShape()
    pts, faces, lm = lumen_surface(shape)
    rows = []

    def row(name, make):
        t0 = time.perf_counter()
        q = quality(make())
        rows.append(f"| {name} | {time.perf_counter() - t0:.2f} | {q['vertices']} | {q['tets']} | "
                    f"{q['min_dihedral_deg']:.1f} | {q['max_dihedral_deg']:.1f} | {q['min_radius_ratio']:.3f} | "
                    f"{q['median_radius_ratio']:.3f} | {q['volume_cm3']:.1f} |")

    def prisms():
        return extrude_wall(pts, faces, from_mm(shape.wall_thickness_mm), lm["entry"],
                            from_mm(shape.cardia_radius_mm), shape.wall_layers)

    wall = prisms()
    row("prism extrusion (mjendo)", prisms)
    for algo in GMSH_ALGORITHMS:
        row(f"gmsh {algo}, same boundary", lambda a=algo: gmsh_wall(wall, None, a))
    for size in sizes_mm:
        for algo in GMSH_ALGORITHMS:
            row(f"gmsh {algo}, boundary remeshed at {size:g} mm", lambda a=algo, s=size: gmsh_wall(wall, s, a))
    head = ("| mesher | s | vertices | tets | min dihedral (deg) | max dihedral (deg) | min radius ratio | "
            "median radius ratio | volume (cm3) |\n|---|---|---|---|---|---|---|---|---|")
    return "\n".join([head, *rows])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.anatomy", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("build", help="generate the stomach mesh and vertex sets")
    b.add_argument("--out", type=Path, help="folder to write (required with --surface; default: the built-in "
                   "stomach's, models/stomach)")
    b.add_argument("--surface", type=Path, help="your closed lumen surface, mm")
    b.add_argument("--entry", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="cardia point on your surface, mm")
    b.add_argument("--axis", type=float, nargs=3, metavar=("DX", "DY", "DZ"),
                   help="insertion direction into the lumen")
    b.add_argument("--thickness", type=float, default=5.0, help="wall thickness, mm")
    g = sub.add_parser("generate", help="print the sizes of generated stomachs (shapes drawn from AnatomyRanges)")
    g.add_argument("--seeds", type=int, nargs="+", default=list(range(8)))
    g.add_argument("--figure", type=Path, help="also draw them side by side (e.g. docs/media/anatomies.png)")
    r = sub.add_parser("report", help="print sizes and mesh quality")
    r.add_argument("--dir", type=Path, default=STOMACH_DIR)
    m = sub.add_parser("meshers", help="the built-in wall by prism extrusion against gmsh (needs gmsh)")
    m.add_argument("--sizes", type=float, nargs="*", default=[10.0, 6.0],
                   help="element sizes (mm) at which gmsh also remeshes the boundary")
    args = ap.parse_args(argv)
    if getattr(args, "surface", None) and (args.entry is None or args.axis is None):
        ap.error("--surface needs --entry and --axis (the cardia and insertion direction)")
    if getattr(args, "surface", None) and args.out is None:
        ap.error("--surface needs --out FOLDER: your stomach gets a folder of its own (the built-in one stays); "
                 "then `python -m mjendo.targets map --anatomy FOLDER`")
    if args.cmd == "build" and args.out is None:
        args.out = STOMACH_DIR

    def command() -> None:
        if args.cmd == "meshers":
            print(meshers_table(args.sizes))
            return
        if args.cmd == "generate":
            stomachs = [generate(seed) for seed in args.seeds]
            for st in stomachs:
                i = st.info
                print(f"seed {i['seed']}: length {i['length_mm']:.0f} mm, greater curvature "
                      f"{i['greater_curvature_mm']:.0f} mm, lesser {i['lesser_curvature_mm']:.0f} mm, wall "
                      f"{i['wall_thickness_mm']:.1f} mm, {len(st.mesh.tets)} tets, min radius ratio "
                      f"{i['min_radius_ratio']:.2f}")
            if args.figure:
                from mjendo import figures

                print(f"wrote {figures.anatomies(stomachs, args.figure)}")
            return
        if args.cmd == "build":
            st = from_surface(args.surface, args.entry, args.axis, args.thickness) if args.surface else build()
            save(st, args.out)
            then = "" if args.out.resolve() == STOMACH_DIR.resolve() else f" --anatomy {args.out}"
            print(f"wrote {args.out}/stomach.msh and stomach.json (then `python -m mjendo.targets map{then}` "
                  "measures its target map)")
        else:
            st = load(args.dir)
        shown = {k: v for k, v in st.info.items() if not isinstance(v, list)}
        print(json.dumps(shown | {"fixed": st.fixed, "forced": st.forced, "targets_a": len(st.targets_a),
                                  "targets_b": len(st.targets_b)}, indent=1))

    return cli.run(command, MeshError)


if __name__ == "__main__":
    raise SystemExit(main())
