"""ParaView output (VTU/XDMF via meshio) and `pdeinv show` pictures.

Files are read back with meshio and must hold the fields that were written, at
the mesh vertices, with zeros on Dirichlet vertices.
"""

import re

import meshio
import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.cli import main
from pdeinv.io.export import predict, read_fields, vertex_values, write_fields
from pdeinv.nets import MLP
from pdeinv.training.trainset import TEST_DATA, seed_stream


@pytest.mark.parametrize("name, kw", [("heat_2d", dict(n=6)), ("heat_2d", dict(n=4, element="P2")),
                                      ("heat_1d", dict(n=10)), ("wave_2d", dict(n=5))])
@pytest.mark.parametrize("suffix", [".vtu", ".xdmf"])
def test_written_fields_read_back(tmp_path, name, kw, suffix):
    p = pdeinv.load_problem(name, **kw)
    x, y = p.sample(2, seed=1)
    xhat = 0.5 * x
    path = write_fields(tmp_path / f"f{suffix}", p, x, xhat, y, p.operator.forward(xhat))
    points, cells, fields = read_fields(path)
    mesh = p.disc.basis.mesh
    assert points.shape == (mesh.nvertices, 3) and cells.shape == mesh.t.T.shape
    np.testing.assert_allclose(points[:, : mesh.dim()], mesh.p.T)
    assert set(fields) == {"x_true", "x_pred", "x_error", "y_obs", "y_pred"}
    np.testing.assert_allclose(fields["x_true"], vertex_values(p.disc, x), rtol=1e-12)
    np.testing.assert_allclose(fields["x_error"], vertex_values(p.disc, xhat - x), atol=1e-14)
    boundary = mesh.boundary_nodes()
    assert np.all(fields["x_true"][:, boundary] == 0)  # Dirichlet vertices
    inner = np.setdiff1d(np.arange(mesh.nvertices), boundary)
    assert np.abs(fields["x_true"][:, inner]).max() > 0
    if suffix == ".vtu":  # plain meshio sees the same arrays ParaView will
        m = meshio.read(path)
        np.testing.assert_allclose(m.point_data["x_pred_1"], fields["x_pred"][1])


def test_sensor_problem_writes_fields_but_not_time_series(tmp_path):
    p = pdeinv.load_problem("heat_sensors_2d", n=6, sensors=4, steps=10, record_every=5)
    x, y = p.sample(1)
    _, _, fields = read_fields(write_fields(tmp_path / "f.vtu", p, x, x, y, y))
    assert set(fields) == {"x_true", "x_pred", "x_error"}
    assert np.all(fields["x_error"] == 0)


def test_bad_arguments(tmp_path):
    p = pdeinv.load_problem("heat_1d", n=8)
    x, _ = p.sample(2)
    with pytest.raises(ValueError, match="suffix '.png'"):
        write_fields(tmp_path / "f.png", p, x, x)
    with pytest.raises(ValueError, match="x_pred has shape"):
        write_fields(tmp_path / "f.vtu", p, x, x[:, :-1])
    with pytest.raises(ValueError, match=r"x_true has shape \(2, 7\) but x_pred has \(1, 7\)"):
        write_fields(tmp_path / "f.vtu", p, x, x[:1])
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_fields(tmp_path / "none.vtu")
    pdeinv.fem.mesh.save(tmp_path / "plain.vtu", p.disc.basis.mesh)
    with pytest.raises(ValueError, match="no x_true"):
        read_fields(tmp_path / "plain.vtu")


def test_cli_train_writes_paraview_files_and_show_draws_them(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "--prior-fit", "0",
            "wave_sensors_2d", "--method", "adam", "--steps", "3", "--out", str(out),
            "--set", "n=6", "--set", "steps=12", "--set", "sensors=8", "--n-train", "16", "--n-test", "4",
            "--batch-size", "4", "--hidden", "8", "--export-samples", "2"]
    assert main(argv) == 0
    _, _, fields = read_fields(out / "fields.vtu")
    assert fields["x_true"].shape[0] == 2
    sensors = meshio.read(out / "sensors.vtu")
    assert sensors.points.shape == (8, 3)
    p = pdeinv.load_problem("wave_sensors_2d", n=6, steps=12, sensors=8)
    model = MLP(p.operator.n_out, p.N, hidden=(8,))  # the prediction in the file is the saved model's
    model.load_state_dict(torch.load(out / "model.pt"))
    x, y = p.sample(4, seed=seed_stream(0, TEST_DATA))  # the trainer's test set
    np.testing.assert_allclose(fields["x_true"], vertex_values(p.disc, x[:2]), rtol=1e-10)
    np.testing.assert_allclose(fields["x_pred"], vertex_values(p.disc, predict(model, y[:2])), atol=1e-6)
    assert (out / "fields.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["show", str(out), "--samples", "1", "--png", str(tmp_path / "one.png")]) == 0
    assert (tmp_path / "one.png").stat().st_size > 1000
    capsys.readouterr()


@pytest.mark.parametrize("argv, match", [
    (["show", "{tmp}/missing"], "is not a directory"),
    (["show", "{tmp}"], "holds no fields.vtu"),
    (["show", "{run}", "--samples", "5"], r"--samples 5 is not allowed; the file holds samples 0..1"),
    (["show", "{run}", "--samples", "a"], "not a comma-separated list"),
    (["train", "--prior-fit", "0",
      "heat_1d", "--out", "{tmp}/r", "--export-samples", "-1"], "--export-samples -1"),
])
def test_show_bad_input_exits_2_with_one_line(tmp_path, capsys, argv, match):
    run = tmp_path / "run"
    run.mkdir()
    p = pdeinv.load_problem("heat_1d", n=8)
    x, _ = p.sample(2)
    write_fields(run / "fields.vtu", p, x, x)
    argv = [a.format(tmp=tmp_path, run=run) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert re.search(match, err), err


def _tetra_field():
    """A P1 field on a tetra mesh with homogeneous Dirichlet conditions (built without pdeinv.fem.forms)."""
    import types

    import scipy.sparse as sp
    import skfem
    from skfem.models.poisson import laplace, mass

    from pdeinv.fem.forms import Discretization

    basis = skfem.Basis(skfem.MeshTet().refined(2), skfem.ElementTetP1())
    free = basis.complement_dofs(basis.get_dofs())
    sub = np.ix_(free, free)
    disc = Discretization(basis, sp.csr_matrix(mass.assemble(basis)[sub]),
                          sp.csr_matrix(laplace.assemble(basis)[sub]), free)
    x = np.random.default_rng(0).standard_normal((2, len(free)))
    return types.SimpleNamespace(disc=disc), x


@pytest.mark.parametrize("suffix", [".vtu", ".xdmf"])
def test_3d_fields_are_written_as_tetra_cells(tmp_path, suffix):
    """The VTU export used to write tetrahedra as line cells."""
    problem, x = _tetra_field()
    mesh = problem.disc.basis.mesh
    path = write_fields(tmp_path / f"f{suffix}", problem, x, 0.5 * x)
    points, cells, fields = read_fields(path)
    assert cells.shape == (mesh.nelements, 4)
    np.testing.assert_array_equal(cells, mesh.t.T)
    np.testing.assert_allclose(points, mesh.p.T)
    np.testing.assert_allclose(fields["x_error"], vertex_values(problem.disc, -0.5 * x))
    if suffix == ".vtu":
        assert [c.type for c in meshio.read(path).cells] == ["tetra"]
    else:
        with meshio.xdmf.TimeSeriesReader(str(path)) as r:
            assert [c.type for c in r.read_points_cells()[1]] == ["tetra"]


def test_cells_without_a_picture_get_a_clear_refusal(tmp_path):
    """3-D tetra fields are drawn as slices (tests/test_3d_io.py); other cells are refused."""
    from pdeinv.io.plots import plot_fields

    problem, x = _tetra_field()
    points, cells, fields = read_fields(write_fields(tmp_path / "f.vtu", problem, x, x))
    with pytest.raises(ValueError, match=r"cells of 8 nodes.*ParaView"):
        plot_fields(points, np.zeros((1, 8), dtype=int), fields)
