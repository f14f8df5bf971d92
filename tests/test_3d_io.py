"""3-D input and output: fields files with tetra cells (P1, P2), slices for ``pdeinv show``,
sensors on tetra meshes, wrong mesh files refused, the listing of problems.
"""

import numpy as np
import pytest
from exact import dot_test, load

from pdeinv import observe
from pdeinv.cli import main
from pdeinv.fem.forms import discretize
from pdeinv.fem.mesh import unit_cube
from pdeinv.io.export import write_fields
from pdeinv.io.plots import mid_slice
from pdeinv.physics import Heat

meshio = pytest.importorskip("meshio")


def area(xy, tris):
    """Total area of planar triangles."""
    (a, b, c) = (xy[tris[:, k]] - xy[tris[:, 0]] for k in range(3))
    return 0.5 * np.abs(b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]).sum()


def smooth(p):
    """A field that is not piecewise linear, so P2 vertex values are not a P1 accident."""
    return np.sin(np.pi * p[0]) * np.sin(np.pi * p[1]) * np.sin(np.pi * p[2]) * (1 + p[0] ** 2)


@pytest.mark.parametrize("element", ["P1", "P2"])
@pytest.mark.parametrize("suffix", [".vtu", ".xdmf"])
def test_fields_round_trip(tmp_path, element, suffix):
    """Written as tetra cells on the mesh vertices; values = the field at the vertices (0 on the
    Dirichlet boundary), read back with meshio."""
    p = load("heat_3d", n=3, element=element, steps=2, backend="steps")
    mesh = p.disc.basis.mesh
    x = smooth(p.points)[None]
    path = write_fields(tmp_path / f"f{suffix}", p, x, 0.5 * x)
    if suffix == ".vtu":
        m = meshio.read(path)
        points, cells, data = m.points, m.cells, m.point_data
    else:
        with meshio.xdmf.TimeSeriesReader(str(path)) as r:
            points, cells = r.read_points_cells()
            _, data, _ = r.read_data(0)
    assert [c.type for c in cells] == ["tetra"] and len(points) == mesh.p.shape[1] == 64
    np.testing.assert_array_equal(cells[0].data, mesh.t.T)
    expected = np.where(np.isclose(np.abs(mesh.p - 0.5).max(axis=0), 0.5), 0.0, smooth(mesh.p))
    np.testing.assert_allclose(data["x_true_0"], expected, atol=1e-12)
    np.testing.assert_allclose(data["x_error_0"], -0.5 * expected, atol=1e-12)


def test_mid_slice_is_the_exact_cut():
    """A linear field is exact on the cut; the cut of the cube has area 1, the cavity's cut
    through its centre has the area of the cube's face minus a disc (polyhedral sphere)."""
    m = unit_cube(3)
    pts = m.p.T
    u = 1 + 2 * pts[:, 0] - 3 * pts[:, 1] + 0.5 * pts[:, 2]
    for axis in range(3):
        xy, tris, W = mid_slice(pts, m.t.T, axis)
        at = np.insert(xy, axis, 0.5 + 1e-7, axis=1)
        np.testing.assert_allclose(W @ u, 1 + 2 * at[:, 0] - 3 * at[:, 1] + 0.5 * at[:, 2], atol=1e-12)
        assert area(xy, tris) == pytest.approx(1.0, abs=1e-9)
    cav = load("heat_cavity_3d", steps=2, backend="steps").disc.basis.mesh
    xy, tris, _ = mid_slice(cav.p.T, cav.t.T, 2)
    hole = 1.0 - area(xy, tris)
    assert 0.8 * np.pi * 0.25**2 < hole < np.pi * 0.25**2


def test_show_draws_3d_slices(tmp_path, capsys):
    """``pdeinv show`` on a 3-D run: a PNG with colour (the fields), not a blank picture."""
    import matplotlib.image

    p = load("heat_3d", n=4, steps=2, backend="steps")
    x, _ = p.sample(2, seed=0)
    run = tmp_path / "run"
    run.mkdir()
    write_fields(run / "fields.vtu", p, x, 0.8 * x)
    assert main(["show", str(run), "--samples", "1"]) == 0
    img = matplotlib.image.imread(run / "fields.png")[..., :3]
    assert img.shape[0] > 500 and img.shape[1] > 500
    coloured = (img.max(axis=2) - img.min(axis=2)) > 0.2
    assert coloured.mean() > 0.02, coloured.mean()


def test_sensors_on_the_boundary_faces_and_inside():
    """Boundary points lie on the faces (inset 0: up to 1e-9 inside) or ``≥ inset`` inside, also on a
    curved (polyhedral) boundary, where points on a face would round outside it; all are well spread;
    a sensor reads a linear field exactly; the 3-D sensor operator is the exact transpose."""
    m = unit_cube(4)
    dist = lambda P: 0.5 - np.abs(P - 0.5).max(axis=1)  # noqa: E731  distance to the cube's faces
    on = observe.boundary_points(m, 20)
    assert on.shape == (20, 3) and dist(on).min() > 0 and dist(on).max() < 1e-8
    inset = observe.boundary_points(m, 20, inset=0.25)
    assert dist(inset).min() >= 0.25 - 1e-12
    gaps = np.linalg.norm(on[:, None] - on[None], axis=2) + np.eye(20)
    assert gaps.min() > 0.2  # farthest-point sampling: no two sensors bunched together
    inside = observe.interior_points(m, 10)
    assert inside.shape == (10, 3) and dist(inside).min() > 0.05
    free = discretize(m, dirichlet=False)
    S = observe.sensor_matrix(free, np.vstack([on, inside]))
    lin = lambda P: 1 + P[0] - 2 * P[1] + 3 * P[2]  # noqa: E731
    np.testing.assert_allclose(S @ lin(free.points), lin(np.vstack([on, inside]).T), atol=1e-12)
    disc = discretize(m)
    with pytest.raises(ValueError, match=r"lies where the field is fixed at 0 \(on the Dirichlet boundary"):
        observe.sensor_matrix(disc, on)
    op = Heat(disc.M, disc.K, steps=6, backend="steps").sensors(observe.sensor_matrix(disc, inset), 2)
    assert op.n_out == 20 * 3
    assert dot_test(op) <= 1e-12
    assert observe.sensor_spec("[[0.5, 0.5, 0.5]]").shape == (1, 3)
    cav = load("heat_cavity_3d", steps=2, backend="steps", dirichlet="outer").disc
    ring = observe.boundary_points(cav.basis.mesh, 400)
    assert (np.linalg.norm(ring - [0.45, 0.55, 0.5], axis=1) < 0.26).sum() > 20  # some on the cavity
    assert observe.sensor_matrix(cav, ring[np.abs(ring - 0.5).max(axis=1) < 0.5 - 1e-8]).shape[1] == cav.N


@pytest.mark.parametrize("cells, match", [
    ([("hexahedron", [[0, 1, 2, 3, 4, 5, 6, 7]])], r"cell types \['hexahedron'\]"),
    ([("tetra", [[0, 1, 3, 4]]), ("hexahedron", [[0, 1, 2, 3, 4, 5, 6, 7]])],
     r"cell types \['hexahedron', 'tetra'\]"),
])
def test_wrong_3d_mesh_files_exit_2_with_one_line(tmp_path, capsys, cells, match):
    import re

    cube = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                     [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float)
    path = tmp_path / "bad.vtu"
    meshio.write(path, meshio.Mesh(cube, [(t, np.array(c)) for t, c in cells]))
    out = tmp_path / "out"
    assert main(["train", "--prior-fit", "0",
                 "heat_3d", "--set", f"mesh={path}", "--steps", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and re.search(match + r".*tetra", err), err
    assert not out.exists() or not any(out.iterdir())


def test_problems_lists_the_3d_scenes(capsys):
    assert main(["problems"]) == 0
    out = capsys.readouterr().out
    for name in ("heat_3d", "wave_3d", "heat_cavity_3d"):
        assert f"\n{name}: " in out or out.startswith(f"{name}: "), name
    assert "dirichlet='cavity'" in out
