"""Meshes read with meshio give the same operators as the built-in ones."""

import numpy as np
import pytest
from exact import load

import pdeinv


@pytest.mark.parametrize("suffix", [".msh", ".vtu", ".vtk"])
def test_file_mesh_equals_builtin(tmp_path, suffix):
    path = tmp_path / f"square{suffix}"
    pdeinv.mesh.save(path, pdeinv.mesh.unit_square(8))
    a, b = load("heat_2d", n=8), load("heat_2d", mesh=str(path))
    assert a.N == b.N
    x = np.random.default_rng(0).standard_normal(a.N)
    # same node order: same matrices, same physics
    assert abs(a.disc.M - b.disc.M).max() < 1e-14 and abs(a.disc.K - b.disc.K).max() < 1e-12
    np.testing.assert_allclose(a.operator.forward(x), b.operator.forward(x), atol=1e-12)


def test_file_mesh_with_boundary_lines_and_3d_points(tmp_path):
    """gmsh-style files: 3-D points with z = 0 and line cells on the boundary."""
    import meshio

    m = pdeinv.mesh.unit_square(4)
    pts = np.c_[m.p.T, np.zeros(m.nvertices)]
    lines = m.facets[:, m.boundary_facets()].T
    path = tmp_path / "g.vtu"
    meshio.write(path, meshio.Mesh(pts, [("line", lines), ("triangle", m.t.T)]))
    p = load("wave_2d", mesh=str(path))
    assert p.points.shape == (2, 9)


def test_interval_and_square():
    assert pdeinv.mesh.interval(10).nelements == 10
    assert pdeinv.mesh.unit_square(3).nelements == 18
    with pytest.raises(ValueError, match="empty"):
        pdeinv.mesh.interval(4, 1.0, 0.0)


def test_sample_is_seeded_and_noisy():
    p = load("heat_1d", n=16, noise=0.05)
    x1, y1 = p.sample(8, seed=3)
    x2, y2 = p.sample(8, seed=3)
    np.testing.assert_array_equal(y1, y2)
    clean = p.operator.forward(x1)
    rel = np.sqrt(((y1 - clean) ** 2).mean(1) / (clean**2).mean(1))
    assert 0.02 < rel.mean() < 0.08
    assert p.points.shape == (1, 15)
