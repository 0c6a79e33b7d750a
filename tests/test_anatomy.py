"""The stomach mesh: anatomy sizes, element quality, vertex sets, reproducibility, bad input."""

import numpy as np
import pytest

from mjendo import anatomy, tetmesh
from mjendo.config import PAPER_GREATER_CURVATURE_MM, PAPER_N_FIXED, PAPER_N_FORCED, PAPER_STOMACH_LENGTH_MM
from mjendo.tetmesh import MeshError


def test_sizes_match_paper(stomach):
    info = anatomy.build().info
    assert abs(info["length_mm"] / PAPER_STOMACH_LENGTH_MM - 1) < 0.05
    assert abs(info["greater_curvature_mm"] / PAPER_GREATER_CURVATURE_MM - 1) < 0.05
    # J shape: the lesser curvature is much shorter than the greater one.
    assert info["lesser_curvature_mm"] < 0.6 * info["greater_curvature_mm"]


def test_mesh_quality(stomach):
    q = tetmesh.quality(stomach.mesh)
    assert q["inverted"] == 0
    assert q["min_dihedral_deg"] > 5.0
    assert q["min_radius_ratio"] > 0.1
    # Wall volume equals outer minus inner enclosed volume (prisms split without overlap).
    b = stomach.mesh.boundary_faces()
    p = stomach.mesh.points
    enclosed = np.einsum("ij,ij->", p[b[:, 0]], np.cross(p[b[:, 1]], p[b[:, 2]])) / 6
    assert enclosed == pytest.approx(stomach.mesh.volumes().sum(), rel=1e-9)


def test_boundary_is_closed_and_hollow(stomach):
    faces = stomach.mesh.boundary_faces()
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # watertight wall surface
    # Hollow: the lumen surface encloses a large cavity (an adult stomach holds ~1 l).
    verts, tris, _ = anatomy.lumen_surface(anatomy.StomachShape())
    lumen_ml = np.einsum("ij,ij->", verts[tris[:, 0]], np.cross(verts[tris[:, 1]], verts[tris[:, 2]])) / 6 * 1e6
    assert 400 < lumen_ml < 2000


def test_vertex_sets(stomach):
    assert len(stomach.fixed) == PAPER_N_FIXED and len(stomach.forced) == PAPER_N_FORCED
    a, b = set(stomach.targets_a), set(stomach.targets_b)
    assert a and b and not (a & b)
    inner = stomach.mesh.inner
    assert all(inner[i] for i in a | b)
    # On the inner wall: the nearest outer-wall vertex is about one wall thickness away.
    outer = stomach.mesh.points[~inner]
    for i in list(a | b):
        d = np.min(np.linalg.norm(outer - stomach.mesh.points[i], axis=1)) * 1e3
        assert 3.0 < d < 8.0
    assert not inner[stomach.fixed].any() and not inner[stomach.forced].any()


def test_committed_mesh_is_current(stomach):
    fresh = anatomy.build()
    np.testing.assert_allclose(fresh.mesh.points, stomach.mesh.points, atol=1e-9)
    np.testing.assert_array_equal(np.sort(fresh.mesh.tets, 1), np.sort(stomach.mesh.tets, 1))
    for key in ("fixed", "forced"):
        assert getattr(fresh, key) == getattr(stomach, key), key
    # The committed lists are the simulation-verified subset of the generator's candidates.
    assert fresh.info["candidates"] == stomach.info["candidates"]
    assert set(stomach.targets_a + stomach.targets_b) <= set(fresh.info["candidates"])


def test_user_surface_roundtrip(tmp_path):
    import trimesh

    # An ellipsoidal "stomach" in millimetres, as a user would export it.
    s = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    s.apply_scale([90.0, 50.0, 45.0])
    path = tmp_path / "lumen.stl"
    s.export(path)
    st = anatomy.from_surface(path, entry_mm=[90.0, 0, 0], axis=[-1, 0, 0], thickness_mm=5.0)
    assert tetmesh.quality(st.mesh)["inverted"] == 0
    assert st.targets_a and st.targets_b
    anatomy.save(st, tmp_path / "mine")
    back = anatomy.load(tmp_path / "mine")
    np.testing.assert_allclose(back.mesh.points, st.mesh.points, atol=1e-9)


def test_open_surface_is_rejected(tmp_path):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=2, radius=80.0)
    s.update_faces(np.arange(len(s.faces)) != 0)  # punch a hole
    path = tmp_path / "open.stl"
    s.export(path)
    with pytest.raises(MeshError, match="not closed"):
        anatomy.from_surface(path, entry_mm=[80, 0, 0], axis=[-1, 0, 0])


def test_inverted_surface_and_wrong_units_are_rejected(tmp_path):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=2, radius=80.0)
    s.invert()
    with pytest.raises(MeshError, match="inwards"):
        tetmesh.check_surface(np.asarray(s.vertices), np.asarray(s.faces))
    tiny = trimesh.creation.icosphere(subdivisions=2, radius=0.08)  # metres, not mm
    path = tmp_path / "metres.stl"
    tiny.export(path)
    with pytest.raises(MeshError, match="millimetres"):
        anatomy.from_surface(path, entry_mm=[0.08, 0, 0], axis=[-1, 0, 0])


def test_missing_and_corrupt_files(tmp_path):
    with pytest.raises(MeshError, match="does not exist"):
        tetmesh.read_msh(tmp_path / "nope.msh")
    bad = tmp_path / "bad.msh"
    bad.write_text("this is not a mesh")
    with pytest.raises(MeshError, match="cannot read"):
        tetmesh.read_msh(bad)
    with pytest.raises(MeshError, match="anatomy build"):
        anatomy.load(tmp_path)
    garbage = tmp_path / "garbage.stl"  # trimesh reads it as an empty mesh: refused, not a NumPy error
    garbage.write_text("this is not a surface")
    with pytest.raises(MeshError, match="holds 0 triangles: give a closed lumen surface"):
        anatomy.from_surface(garbage, entry_mm=[80, 0, 0], axis=[-1, 0, 0])


def test_an_entry_axis_that_is_no_direction_is_refused(tmp_path):
    import trimesh

    path = tmp_path / "sphere.stl"
    trimesh.creation.icosphere(subdivisions=2, radius=80.0).export(path)
    with pytest.raises(MeshError, match="is no direction"):
        anatomy.from_surface(path, entry_mm=[80, 0, 0], axis=[0, 0, 0])


def test_gmsh_tetrahedralises_the_same_wall_and_remeshing_buys_shape_with_elements(stomach):
    try:
        import gmsh  # noqa: F401
    except (ImportError, OSError) as exc:  # not installed, or its system libraries are missing
        pytest.skip(f"the mesher comparison needs the optional extra mjendo[mesh]: {exc}")
    prisms = tetmesh.quality(stomach.mesh)
    same = tetmesh.quality(tetmesh.gmsh_wall(stomach.mesh, None, "hxt"))
    # The same boundary, no point added: the same wall, as many tets, none inverted, no worse an element.
    assert same["vertices"] == prisms["vertices"] and same["inverted"] == 0
    assert same["volume_cm3"] == pytest.approx(prisms["volume_cm3"], rel=1e-6)
    assert same["min_radius_ratio"] >= prisms["min_radius_ratio"]
    remeshed = tetmesh.quality(tetmesh.gmsh_wall(stomach.mesh, 10.0, "hxt"))
    assert remeshed["median_radius_ratio"] > 2 * prisms["median_radius_ratio"]  # near-regular tets ...
    assert remeshed["tets"] > 5 * prisms["tets"]  # ... at several times the elements (and the step cost)
    assert remeshed["volume_cm3"] == pytest.approx(prisms["volume_cm3"], rel=0.02)
    with pytest.raises(MeshError, match="unknown gmsh algorithm"):
        tetmesh.gmsh_wall(stomach.mesh, None, "frontal")


def test_the_mesher_comparison_without_gmsh_says_how_to_install_it(monkeypatch, capsys):
    import sys

    monkeypatch.setitem(sys.modules, "gmsh", None)
    assert anatomy.main(["meshers", "--sizes"]) == 2
    assert "comparing meshers needs gmsh: pip install gmsh" in capsys.readouterr().err


def test_generated_stomachs_are_deterministic_plausible_and_differ():
    from dataclasses import fields

    from mjendo.config import AnatomyRanges

    stomachs = [anatomy.generate(seed) for seed in range(6)]
    again = anatomy.generate(3)
    np.testing.assert_array_equal(again.mesh.points, stomachs[3].mesh.points)
    assert again.fixed == stomachs[3].fixed and again.forced == stomachs[3].forced
    lengths = [st.info["length_mm"] for st in stomachs]
    assert len({round(x) for x in lengths}) == len(lengths)  # every seed its own stomach
    for st in stomachs:
        shape = st.info["shape"]
        for f in fields(AnatomyRanges):
            lo, hi = getattr(AnatomyRanges(), f.name)
            assert lo <= shape[f.name] <= hi, f.name
        assert 160.0 < st.info["length_mm"] < 235.0  # adult stomachs on MRI: 184-226 mm
        assert st.mesh.volumes().min() > 0 and st.info["min_radius_ratio"] > 0.1
        # The pyloric anchor sits at the pyloric end, the loaded vertices on top of the fundus.
        verts, _, lm = anatomy.lumen_surface(anatomy.sample_shape(st.info["seed"]))
        assert np.linalg.norm(st.mesh.points[st.fixed[2]] - verts[lm["bottom"]]) < 0.015
        top = st.mesh.points[:, 2].max()
        assert all(top - st.mesh.points[v, 2] < 0.010 for v in st.forced)  # the apex and its first ring


def test_generate_command_prints_sizes_and_draws(tmp_path, capsys):
    out = tmp_path / "anatomies.png"
    assert anatomy.main(["generate", "--seeds", "0", "1", "--figure", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.count("greater curvature") == 2 and out.stat().st_size > 10_000
