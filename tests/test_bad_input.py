"""Bad input meets a ValueError/FileNotFoundError that names the value and what is allowed."""

import numpy as np
import pytest
from exact import load

import pdeinv
from pdeinv.cli import main


@pytest.mark.parametrize("name, overrides, match", [
    ("heat_2d", dict(T=0), r"T=0.*> 0"),
    ("heat_2d", dict(T=-1.0), r"T=-1.0.*> 0"),
    ("heat_1d", dict(steps=0), r"steps=0.*integer >= 1"),
    ("heat_1d", dict(steps=2.5), r"steps=2.5.*integer"),
    ("heat_1d", dict(n=0), r"n=0.*integer >= 1"),
    ("heat_1d", dict(kappa=float("nan")), r"kappa=nan.*finite"),
    ("heat_1d", dict(kappa="abc"), r"kappa='abc' is not a number"),
    ("heat_1d", dict(scheme="rk4"), r"scheme='rk4'.*'be', 'cn'"),
    ("heat_1d", dict(backend="gpu"), r"backend='gpu'.*'auto', 'steps', 'modal'"),
    ("heat_1d", dict(element="P3"), r"element='P3'.*'P1', 'P2'"),
    ("heat_1d", dict(noise=-0.1), r"noise=-0.1.*>= 0"),
    ("heat_1d", dict(kapa=0.1), r"unknown setting.*'kapa'.*allowed: .*kappa"),
    ("wave_1d", dict(c=0), r"c=0.*> 0"),
    ("wave_1d", dict(kappa=0.1), r"unknown setting.*'kappa'"),
])
def test_bad_overrides(name, overrides, match):
    with pytest.raises(ValueError, match=match):
        load(name, **overrides)


def test_string_overrides_are_coerced():
    p = load("heat_1d", n="16", kappa="0.02", steps="10")
    assert p.N == 15 and p.operator.kappa == 0.02 and p.operator.steps == 10


@pytest.mark.parametrize("name", ["heat_1d", "wave_1d"])
def test_operator_rejects_bad_arrays(name):
    op = load(name, n=8).operator
    with pytest.raises(ValueError, match=r"shape \(3, 8\); expected \(B, 7\)"):
        op.forward(np.zeros((3, 8)))
    with pytest.raises(ValueError, match=r"shape \(2, 3, 7\)"):
        op.adjoint(np.zeros((2, 3, 7)))
    bad = np.zeros((2, 7))
    bad[1, 4] = np.inf
    with pytest.raises(ValueError, match=r"NaN or Inf \(first at index \(1, 4\)\)"):
        op.forward(bad)
    with pytest.raises(ValueError, match="complex"):
        op.forward(np.zeros((1, 7), dtype=complex))
    with pytest.raises(ValueError, match="dtype"):
        op.forward(np.array([["a"] * 7]))


def test_unknown_problem_and_module_without_make(tmp_path):
    with pytest.raises(ValueError, match=r"unknown problem 'heat_3d'; available: .*heat_2d"):
        pdeinv.load_problem("heat_3d")
    with pytest.raises(FileNotFoundError, match="nope.py"):
        pdeinv.load_problem(tmp_path / "nope.py")
    mod = tmp_path / "nomake.py"
    mod.write_text("x = 1\n")
    with pytest.raises(ValueError, match="no function make"):
        pdeinv.load_problem(mod)


def test_mesh_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.msh"):
        load("heat_2d", mesh=str(tmp_path / "missing.msh"))
    garbage = tmp_path / "garbage.vtu"
    garbage.write_text("this is not a mesh")
    with pytest.raises(ValueError, match="could not be read by meshio"):
        load("heat_2d", mesh=str(garbage))
    empty = tmp_path / "empty.msh"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match="could not be read"):
        load("heat_2d", mesh=str(empty))


def test_unsupported_cells(tmp_path):
    import meshio

    quads = tmp_path / "quads.vtu"
    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    meshio.write(quads, meshio.Mesh(pts, [("quad", np.array([[0, 1, 2, 3]]))]))
    with pytest.raises(ValueError, match=r"cell types \['quad'\]"):
        load("heat_2d", mesh=str(quads))
    mixed = tmp_path / "mixed.vtu"
    pts5 = np.vstack([pts, [[2, 0]]])
    meshio.write(mixed, meshio.Mesh(pts5, [("quad", np.array([[0, 1, 2, 3]])),
                                           ("triangle", np.array([[1, 4, 2]]))]))
    with pytest.raises(ValueError, match=r"\['quad', 'triangle'\]"):
        load("heat_2d", mesh=str(mixed))


def test_cli_reports_one_line_and_exit_code_2(capsys):
    assert main(["demo", "heat_1d", "--set", "T=-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "T=-1.0" in err[0] and "Traceback" not in err[0]
    assert main(["demo", "heat_1d", "--set", "oops"]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err
