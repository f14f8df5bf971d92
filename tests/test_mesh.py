"""Meshes read with meshio give the same operators as the built-in ones."""

import numpy as np
import pytest
from exact import load

import pdeinv
from pdeinv.fem.forms import discretize


@pytest.mark.parametrize("suffix", [".msh", ".vtu", ".vtk"])
def test_file_mesh_equals_builtin(tmp_path, suffix):
    path = tmp_path / f"square{suffix}"
    pdeinv.fem.mesh.save(path, pdeinv.fem.mesh.unit_square(8))
    a, b = load("heat_2d", n=8), load("heat_2d", mesh=str(path))
    assert a.N == b.N
    x = np.random.default_rng(0).standard_normal(a.N)
    # same node order: same matrices, same physics
    assert abs(a.disc.M - b.disc.M).max() < 1e-14 and abs(a.disc.K - b.disc.K).max() < 1e-12
    np.testing.assert_allclose(a.operator.forward(x), b.operator.forward(x), atol=1e-12)


def test_file_mesh_with_boundary_lines_and_3d_points(tmp_path):
    """gmsh-style files: 3-D points with z = 0 and line cells on the boundary."""
    import meshio

    m = pdeinv.fem.mesh.unit_square(4)
    pts = np.c_[m.p.T, np.zeros(m.nvertices)]
    lines = m.facets[:, m.boundary_facets()].T
    path = tmp_path / "g.vtu"
    meshio.write(path, meshio.Mesh(pts, [("line", lines), ("triangle", m.t.T)]))
    p = load("wave_2d", mesh=str(path))
    assert p.points.shape == (2, 9)


def test_interval_and_square():
    assert pdeinv.fem.mesh.interval(10).nelements == 10
    assert pdeinv.fem.mesh.unit_square(3).nelements == 18
    with pytest.raises(ValueError, match="empty"):
        pdeinv.fem.mesh.interval(4, 1.0, 0.0)


def test_sample_is_seeded_and_noisy():
    p = load("heat_1d", n=16, noise=0.05)
    x1, y1 = p.sample(8, seed=3)
    x2, y2 = p.sample(8, seed=3)
    np.testing.assert_array_equal(y1, y2)
    clean = p.operator.forward(x1)
    rel = np.sqrt(((y1 - clean) ** 2).mean(1) / (clean**2).mean(1))
    assert 0.02 < rel.mean() < 0.08
    assert p.points.shape == (1, 15)


# -- one table of cell types: line, triangle, tetra; anything else is refused ----------------------

def _cells(path):
    import meshio

    return sorted({c.type for c in meshio.read(path).cells})


@pytest.mark.parametrize("suffix", [".msh", ".vtu"])
def test_tetra_mesh_round_trips(tmp_path, suffix):
    """3-D meshes used to be written as line cells (and read back as nonsense)."""
    import skfem

    m = skfem.MeshTet().refined(1)
    pdeinv.fem.mesh.save(tmp_path / f"cube{suffix}", m)
    assert _cells(tmp_path / f"cube{suffix}") == ["tetra"]
    back = pdeinv.fem.mesh.load(tmp_path / f"cube{suffix}")
    assert type(back) is skfem.MeshTet1
    np.testing.assert_array_equal(back.t, m.t)
    np.testing.assert_allclose(back.p, m.p)


@pytest.mark.parametrize("make, facet", [
    (lambda: pdeinv.fem.mesh.interval(4), "vertex"),
    (lambda: pdeinv.fem.mesh.unit_square(3), "line"),
    (lambda: __import__("skfem").MeshTet().refined(1), "triangle"),
])
def test_named_boundaries_round_trip_in_every_dimension(tmp_path, make, facet):
    """Named boundaries are written as physical groups of the facet cells (points, lines, triangles)."""
    m = make()
    m = m.with_boundaries({"low": lambda x: np.isclose(x[0], 0.0), "high": lambda x: np.isclose(x[0], 1.0)})
    pdeinv.fem.mesh.save(tmp_path / "m.msh", m)
    assert facet in _cells(tmp_path / "m.msh")
    back = pdeinv.fem.mesh.load(tmp_path / "m.msh")
    assert sorted(back.boundaries) == ["high", "low"]
    for name, x in (("low", 0.0), ("high", 1.0)):
        assert len(back.boundaries[name]) == len(m.boundaries[name]) > 0
        assert np.allclose(back.p[0, back.facets[:, back.boundaries[name]]], x)


@pytest.mark.parametrize("name", ["MeshQuad1", "MeshHex1", "MeshTri2", "MeshTet2", "MeshLine1DG"])
@pytest.mark.parametrize("suffix", [".msh", ".vtu"])
def test_save_refuses_unsupported_meshes(tmp_path, name, suffix):
    import skfem

    m = getattr(skfem, name)()
    with pytest.raises(ValueError, match=rf"{name}.*not supported.*MeshLine1, MeshTri1, MeshTet1"):
        pdeinv.fem.mesh.save(tmp_path / f"m{suffix}", m)
    assert not (tmp_path / f"m{suffix}").exists()


@pytest.mark.parametrize("cells, match", [
    ([("hexahedron", [[0, 1, 2, 3, 4, 5, 6, 7]])], r"cell types \['hexahedron'\]"),
    ([("tetra", [[0, 1, 2, 4]]), ("wedge", [[0, 1, 2, 3, 5, 6]])], r"\['tetra', 'wedge'\]"),
    ([("triangle6", [[0, 1, 2, 3, 4, 5]])], r"\['triangle6'\]"),
])
def test_load_refuses_unsupported_cells(tmp_path, cells, match):
    import meshio

    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1.0]])
    meshio.write(tmp_path / "m.vtu", meshio.Mesh(pts, [(k, np.array(c)) for k, c in cells]))
    with pytest.raises(ValueError, match=match + r".*supported.*line, triangle or tetra"):
        pdeinv.fem.mesh.load(tmp_path / "m.vtu")


def test_tetra_meshes_discretize_and_others_are_refused():
    import skfem

    d = discretize(skfem.MeshTet().refined(2), dirichlet=False)
    assert abs(d.measure - 1.0) < 1e-12 and d.dim == 3
    assert abs(d.K @ np.ones(d.N)).max() < 1e-12  # constants are in the kernel of the Neumann stiffness
    with pytest.raises(ValueError, match=r"MeshQuad1 is not supported.*MeshTet1"):
        discretize(skfem.MeshQuad())
