"""Every subcommand on every built-in scene, degenerate but valid data included (issue 48, item 4):
``pdeinv demo`` on the nonlinear scenes (their adjoint is the linearization's, ``vjp``), and data with a
few all-zero rows (empty boxes): relative errors of a zero row are taken against the rms norm of the
batch's nonzero rows (:func:`pdeinv.fem.forms.relative_norms`), so ``train`` does not blame the learning
rate, ``classical`` prints valid JSON and ``predict`` no ``x_err inf``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.fem.forms import relative_norms

pytestmark = pytest.mark.usefixtures("one_thread")

ZEROS = [3, 100, 290, 295]  # rows made all-zero: two train rows, two of the last 20 (the test rows)


@pytest.mark.parametrize("name, n", [("allen_cahn_1d", 16), ("sine_gordon_1d", 16), ("allen_cahn_2d", 6),
                                     ("sine_gordon_2d", 6)])
def test_demo_on_the_nonlinear_scenes(capsys, name, n):
    assert main(["demo", name, "--batch", "2", "--set", f"n={n}"]) == 0
    out = capsys.readouterr().out
    assert "nonlinear (adjoint: P'(x)^T r" in out
    dot = float(next(line for line in out.splitlines() if "dot_product_test" in line).split(":")[1])
    assert dot < 1e-10


def test_relative_error_of_zero_rows():
    p = pdeinv.load_problem("heat_1d", n=16)
    x = p.sample(4, seed=0)[0]
    xhat = x + 0.01 * p.sample(4, seed=1)[0]
    before = p.relative_error(xhat, x)
    x0, xhat0 = x.copy(), xhat.copy()
    x0[1] = 0.0
    err = p.relative_error(xhat0, x0)
    assert np.isfinite(err).all()
    np.testing.assert_allclose(err[[0, 2, 3]], before[[0, 2, 3]])  # nonzero rows: as before
    rms = np.sqrt(np.mean(p.disc.norm(x0[[0, 2, 3]]) ** 2))
    np.testing.assert_allclose(err[1], p.disc.norm(xhat0[1] - x0[1])[0] / rms)
    xhat0[1] = 0.0
    assert p.relative_error(xhat0, x0)[1] == 0.0  # a zero row reproduced exactly
    np.testing.assert_allclose(relative_norms(np.array([2.0, 3.0]), np.zeros(2)), [2.0, 3.0])  # all zero
    assert math.isnan(relative_norms(np.array([1.0]), np.array([np.nan]))[0])  # NaN stays NaN


@pytest.fixture(scope="module")
def zeros(tmp_path_factory):
    d = tmp_path_factory.mktemp("zeros")
    p = pdeinv.load_problem("heat_1d", n=16)
    x, y = p.sample(300, seed=0)
    x[ZEROS], y[ZEROS] = 0.0, 0.0
    np.savez(d / "zeros.npz", x=x, y=y)
    np.savez(d / "obs.npz", x=x[-20:], y=y[-20:])
    return d


def test_train_on_zero_rows(zeros, capsys):
    out = zeros / "run"
    code = main(["train", "heat_1d", "--set", "n=16", "--data", str(zeros / "zeros.npz"), "--n-test", "20",
                 "--steps", "2", "--prior-fit", "0", "-q", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "blew up" not in err and "learning rate" not in err and "divide" not in err, err
    assert "repeat" not in err, err  # empty boxes are not repeated measurements
    metrics = json.loads((out / "metrics.json").read_text())
    assert math.isfinite(metrics["x_err"]) and math.isfinite(metrics["y_err"])


def _strict(text):
    def refuse(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=refuse)


def test_classical_on_zero_rows_prints_valid_json(zeros, capsys):
    code = main(["classical", "heat_1d", "--set", "n=16", "--data", str(zeros / "zeros.npz"),
                 "--out", str(zeros / "c.json")])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "Traceback" not in cap.err and "RuntimeWarning" not in cap.err, cap.err
    for line in cap.out.splitlines():
        _strict(line.split(": ", 1)[1])
    rows = _strict((zeros / "c.json").read_text())
    assert rows["tikhonov_best_common_alpha"]["x_err"] < 0.5


def test_predict_on_zero_rows(zeros, capsys):
    if not (zeros / "run" / "model.pt").is_file():
        assert main(["train", "heat_1d", "--set", "n=16", "--data", str(zeros / "zeros.npz"), "--n-test",
                     "20", "--steps", "2", "--prior-fit", "0", "-q", "--out", str(zeros / "run")]) == 0
    code = main(["predict", str(zeros / "run"), "--data", str(zeros / "obs.npz"), "--out",
                 str(zeros / "p.npz")])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "inf" not in cap.out and "nan" not in cap.out and "RuntimeWarning" not in cap.err, cap
    assert float(cap.out.split("x_err ")[1].split()[0].rstrip(",;")) < 0.5


def test_classical_never_prints_nan(monkeypatch, zeros, capsys):
    from pdeinv.cli.commands import classical

    real = classical._solves
    monkeypatch.setattr(classical, "_solves", lambda *a: {**real(*a), "broken": {"x_err": float("nan")}})
    assert main(["classical", "heat_1d", "--set", "n=16", "--data", str(zeros / "zeros.npz")]) == 1
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err == "pdeinv classical: numerical failure: the broken x_err is nan: " \
        "that solve failed on this file (non-finite rows? check the data with numpy.isfinite)\n"
