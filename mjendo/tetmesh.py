"""Volumetric wall meshes: extrude a lumen surface into tets, check quality, read/write.

One code path serves the built-in stomach and a user's own surface: the lumen
(inner wall) surface is extruded outwards by the wall thickness and every
prism is split into three tetrahedra with the min-index rule, which keeps the
split conforming between neighbours without any mesher.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


class MeshError(ValueError):
    """A mesh cannot be used as a stomach; the message says why and what to do."""


@dataclass
class TetMesh:
    """A tetrahedral wall mesh in metres; ``inner`` marks lumen-surface vertices."""

    points: np.ndarray  # (N, 3) float64, metres
    tets: np.ndarray  # (M, 4) int64, positively oriented
    inner: np.ndarray  # (N,) bool: vertex lies on the lumen (inner) surface

    def volumes(self) -> np.ndarray:
        return signed_volumes(self.points, self.tets)

    def boundary_faces(self) -> np.ndarray:
        return boundary_faces(self.tets)


# Face k of a positive tet is opposite vertex k, ordered so its normal points out.
OUTWARD_FACES = ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1))


def signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a, b, c, d = (points[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """Faces that belong to exactly one tet, oriented outwards."""
    # Faces opposite each vertex, ordered so their normal points away from it.
    local = np.array(OUTWARD_FACES)
    faces = tets[:, local].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


def vertex_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of a triangle surface."""
    fn = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    vn = np.zeros_like(points)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    if np.any(norm < 1e-15):
        raise MeshError("surface has isolated or degenerate vertices; clean the mesh "
                        "(e.g. trimesh's remove_unreferenced_vertices) and retry")
    return vn / norm


def _split_prism(v: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Split prism (v0 v1 v2 bottom, v3 v4 v5 top) into 3 tets, min-index rule.

    Each quad face is cut through its smallest global index, so two prisms
    sharing a face cut it the same way (Dompierre et al., 1999).
    """
    # Symmetries of the prism that move the smallest vertex to position 0.
    perms = [(0, 1, 2, 3, 4, 5), (1, 2, 0, 4, 5, 3), (2, 0, 1, 5, 3, 4),
             (3, 5, 4, 0, 2, 1), (4, 3, 5, 1, 0, 2), (5, 4, 3, 2, 1, 0)]
    p = perms[int(np.argmin(v))]
    w = v[list(p)]
    if min(w[1], w[5]) < min(w[2], w[4]):
        return [(w[0], w[1], w[2], w[5]), (w[0], w[1], w[5], w[4]), (w[0], w[4], w[5], w[3])]
    return [(w[0], w[1], w[2], w[4]), (w[0], w[4], w[2], w[5]), (w[0], w[4], w[5], w[3])]


def check_surface(points: np.ndarray, faces: np.ndarray) -> None:
    """Raise MeshError unless the surface is closed, manifold and outward oriented."""
    if points.ndim != 2 or points.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshError("surface must be triangles: points (N,3) and faces (M,3)")
    if len(faces) < 4:
        raise MeshError("surface has fewer than 4 triangles")
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, counts = np.unique(key, axis=0, return_counts=True)
    if np.any(counts != 2):
        raise MeshError(f"surface is not closed: {int(np.sum(counts == 1))} open edges and "
                        f"{int(np.sum(counts > 2))} non-manifold edges; fill holes "
                        "(e.g. trimesh.repair.fill_holes) or re-export a watertight lumen")
    _, dcounts = np.unique(edges, axis=0, return_counts=True)
    if np.any(dcounts != 1):
        raise MeshError("surface winding is inconsistent; fix it with "
                        "trimesh.repair.fix_winding before use")
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    volume = np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0
    if volume <= 0:
        raise MeshError("surface normals point inwards (negative enclosed volume); "
                        "flip the faces (trimesh.repair.fix_inversion)")


def extrude_wall(points: np.ndarray, faces: np.ndarray, thickness: float,
                 entry: np.ndarray, entry_radius: float, layers: int = 1) -> TetMesh:
    """Wall of given thickness outside the lumen surface in ``layers`` prism layers, opened at ``entry``.

    Prisms whose lumen triangle lies within ``entry_radius`` of the entry point
    are removed: that hole is the cardia the endoscope passes through.
    """
    if layers < 1:
        raise MeshError(f"the wall needs at least one element layer (got {layers})")
    check_surface(points, faces)
    normals = vertex_normals(points, faces)
    n = len(points)
    shells = [points + (k / layers) * thickness * normals for k in range(layers + 1)]
    centroids = points[faces].mean(axis=1)
    keep = np.linalg.norm(centroids - entry, axis=1) > entry_radius
    if keep.all():
        raise MeshError("the entry point is farther than entry_radius from every lumen "
                        "triangle: move it onto the surface or enlarge the radius")
    tets = [t for k in range(layers) for f in faces[keep]
            for t in _split_prism(np.array([*(f + k * n), *(f + (k + 1) * n)]))]
    tets = np.asarray(tets, dtype=np.int64)
    all_points = np.concatenate(shells)
    inner = np.arange(len(all_points)) < n
    # Drop vertices that only belonged to removed prisms; reindex.
    used = np.zeros(len(all_points), bool)
    used[tets.ravel()] = True
    remap = -np.ones(len(all_points), np.int64)
    remap[used] = np.arange(used.sum())
    mesh = TetMesh(all_points[used], remap[tets], inner[used])
    return orient(mesh)


def orient(mesh: TetMesh) -> TetMesh:
    """Make every tet positively oriented; refuse degenerate ones."""
    vol = mesh.volumes()
    scale = np.median(np.abs(vol))
    if np.any(np.abs(vol) < 1e-6 * scale):
        raise MeshError(f"{int(np.sum(np.abs(vol) < 1e-6 * scale))} degenerate (flat) tets; "
                        "the wall is thicker than the surface's local curvature allows: "
                        "reduce the thickness or smooth/refine the surface")
    tets = mesh.tets.copy()
    neg = vol < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return TetMesh(mesh.points, tets, mesh.inner)


def dihedral_angles(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """All 6 interior dihedral angles of each tet, degrees, shape (M, 6)."""
    p = points[tets]
    normals = np.stack([np.cross(p[:, b] - p[:, a], p[:, c] - p[:, a]) for a, b, c in OUTWARD_FACES], 1)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    cos = np.stack([-np.einsum("ij,ij->i", normals[:, a], normals[:, b]) for a, b in pairs], 1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def radius_ratio(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """3 * inradius / circumradius per tet: 1 for a regular tet, 0 for a sliver."""
    p = points[tets]
    vol = np.abs(signed_volumes(points, tets))
    area = sum(0.5 * np.linalg.norm(np.cross(p[:, b] - p[:, a], p[:, c] - p[:, a]), axis=1)
               for a, b, c in OUTWARD_FACES)
    inr = 3 * vol / area
    a, b, c, d = (p[:, i] for i in range(4))
    # Circumradius via |a|^2 terms relative to vertex a.
    ba, ca, da = b - a, c - a, d - a
    num = (np.einsum("ij,ij->i", ba, ba)[:, None] * np.cross(ca, da)
           + np.einsum("ij,ij->i", ca, ca)[:, None] * np.cross(da, ba)
           + np.einsum("ij,ij->i", da, da)[:, None] * np.cross(ba, ca))
    circ = np.linalg.norm(num, axis=1) / (12 * vol)
    return 3 * inr / circ


def quality(mesh: TetMesh) -> dict:
    """Element count and shape figures for reports and tests."""
    dih = dihedral_angles(mesh.points, mesh.tets)
    rr = radius_ratio(mesh.points, mesh.tets)
    vol = mesh.volumes()
    return {
        "vertices": int(len(mesh.points)),
        "tets": int(len(mesh.tets)),
        "inverted": int(np.sum(vol <= 0)),
        "min_dihedral_deg": float(dih.min()),
        "max_dihedral_deg": float(dih.max()),
        "min_radius_ratio": float(rr.min()),
        "median_radius_ratio": float(np.median(rr)),
        "volume_cm3": float(vol.sum() * 1e6),
    }


def write_msh(mesh: TetMesh, path: Path) -> None:
    """Write gmsh 4.1 ascii, one node block (the form MuJoCo's flexcomp reads)."""
    import meshio

    meshio.write(str(path), meshio.Mesh(mesh.points, [("tetra", mesh.tets)]),
                 file_format="gmsh", binary=False)


def read_msh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Points and tets from a gmsh/any meshio-readable volume mesh, with clear errors."""
    import meshio

    path = Path(path)
    if not path.exists():
        raise MeshError(f"mesh file {path} does not exist")
    try:
        # Naming the format for .msh also keeps meshio from printing an empty line while it guesses.
        m = meshio.read(str(path), file_format="gmsh" if path.suffix == ".msh" else None)
    except (Exception, SystemExit) as exc:  # meshio raises many types, even SystemExit
        raise MeshError(f"cannot read {path}: {exc}; export it as gmsh 4.1 (.msh)") from exc
    tets = [c.data for c in m.cells if c.type == "tetra"]
    if not tets:
        raise MeshError(f"{path} has no tetrahedra; give a tet mesh, or a closed lumen "
                        "surface (.stl/.obj/.ply) to be extruded into a wall")
    return np.asarray(m.points, np.float64), np.concatenate(tets).astype(np.int64)


GMSH_ALGORITHMS = {"delaunay": 1, "hxt": 10}  # gmsh's Mesh.Algorithm3D codes


def gmsh_wall(wall: TetMesh, size_mm: float | None = None, algorithm: str = "hxt") -> TetMesh:
    """The same wall tetrahedralised by gmsh (the paper's mesher): on the wall's own boundary triangles
    (``size_mm`` None), or with the boundary remeshed at ``size_mm`` first. For comparing meshers: the
    result does not mark its lumen vertices (``inner`` all False)."""
    try:
        import gmsh
    except (ImportError, OSError) as exc:  # OSError: its shared library or the X11/GL ones it links are missing
        raise MeshError(f"comparing meshers needs gmsh: pip install gmsh ({exc})") from exc
    if algorithm not in GMSH_ALGORITHMS:
        raise MeshError(f"unknown gmsh algorithm {algorithm!r}; valid: {', '.join(GMSH_ALGORITHMS)}")
    bnd = boundary_faces(wall.tets)
    on = np.unique(bnd)
    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Verbosity", 0)
        surface = gmsh.model.addDiscreteEntity(2)
        gmsh.model.mesh.addNodes(2, surface, (on + 1).tolist(), wall.points[on].ravel().tolist())
        gmsh.model.mesh.addElementsByType(surface, 2, [], (bnd + 1).ravel().tolist())
        surfaces = [surface]
        if size_mm is not None:  # split the boundary at its sharp rims, rebuild it as geometry, remesh it
            gmsh.model.mesh.classifySurfaces(np.radians(40), True, True, np.pi)
            gmsh.model.mesh.createGeometry()
            surfaces = [tag for _, tag in gmsh.model.getEntities(2)]
            for name in ("Mesh.MeshSizeMin", "Mesh.MeshSizeMax"):
                gmsh.option.setNumber(name, size_mm * 1e-3)
        gmsh.model.geo.addVolume([gmsh.model.geo.addSurfaceLoop(surfaces)])
        gmsh.model.geo.synchronize()
        gmsh.option.setNumber("Mesh.Algorithm3D", GMSH_ALGORITHMS[algorithm])
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        _, nodes = gmsh.model.mesh.getElementsByType(4)
    finally:
        gmsh.finalize()
    row = np.full(int(np.max(tags)) + 1, -1, np.int64)
    row[np.asarray(tags, np.int64)] = np.arange(len(tags))
    points, tets = np.asarray(coords).reshape(-1, 3), row[np.asarray(nodes, np.int64)].reshape(-1, 4)
    used = np.unique(tets)
    remap = np.full(len(points), -1, np.int64)
    remap[used] = np.arange(len(used))
    return orient(TetMesh(points[used], remap[tets], np.zeros(len(used), bool)))
