"""Data in the user's units (pdeinv.problem.units): a linear problem's file scaled by 1e±30 or 1e±100
trains to the same run as in the scene's units and is answered in the file's units; nonlinear physics
refuses it in one line. Before: 1e30 ended in "xhat contains NaN or Inf", 1e100 in a traceback, and the
prior stage kept nothing for data of magnitude 1e-2 (Adam's absolute ε)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.cli import main
from pdeinv.io.export import predict
from pdeinv.problem.units import AS_IS, InUnits, units_of
from pdeinv.training.trainer import Trainer

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def heat():
    return pdeinv.load_problem("heat_1d", n=16, noise=0.01)


@pytest.fixture(scope="module")
def pairs(heat):
    from pdeinv.problem.sampling import add_noise

    x, y = heat.sample(600, seed=4)
    return x, add_noise(y, 0.01, np.random.default_rng(0))


@pytest.fixture(scope="module")
def runs(heat, pairs):
    """The default pipeline (rule, prior stage, calibration) on the same file in three units."""
    x, y = pairs
    return {c: Trainer(heat, "sip", data=y * c, data_x=x * c, steps=5, n_test=40, progress=False).fit()
            for c in (1.0, 1e-2, 1e30)}


def test_units_are_a_power_of_ten_outside_the_float32_safe_window():
    assert units_of(np.array([[0.0, 0.3]])) == 1.0 and units_of(np.zeros((2, 3))) == 1.0
    assert units_of(np.array([[AS_IS[1]]])) == 1.0
    assert units_of(np.array([[3e30, -1.0]])) == 1e30 and units_of(np.array([[-7e-101]])) == 1e-100


@pytest.mark.parametrize("c", [1e-2, 1e30])
def test_a_file_in_other_units_trains_the_same_run_answered_in_its_units(runs, pairs, c):
    x, y = pairs
    ref, run = runs[1.0], runs[c]
    assert run.metrics["data"]["units"] == (1.0 if c == 1e-2 else c)
    for key in ("x_err", "y_err"):
        assert run.metrics[key] == pytest.approx(ref.metrics[key], rel=1e-3)
    assert [s.get("kept") for s in run.metrics["stages"]] == [s.get("kept") for s in ref.metrics["stages"]]
    np.testing.assert_allclose(predict(run.model, y[-40:] * c) / c, predict(ref.model, y[-40:]),
                               rtol=1e-3, atol=1e-3 * np.abs(x).max())
    np.testing.assert_allclose(run.posterior.std / c, ref.posterior.std, rtol=1e-2)
    assert run.metrics["posterior"]["width_90"] / c == pytest.approx(ref.metrics["posterior"]["width_90"],
                                                                      rel=1e-2)


def test_a_run_in_other_units_saves_and_loads_with_its_units(runs, pairs, tmp_path):
    _, y = pairs
    run = runs[1e30]
    assert isinstance(run.model, InUnits)
    # no network_spec: the Trainer's network says how it was built (a data file's base: nets.data_base);
    # with {"kind": "default"} a data-trained network did not fit its own run.json
    pdeinv.save_run(tmp_path / "r", "heat_1d", {"n": 16, "noise": 0.01}, model=run.model,
                    posterior=run.posterior)
    assert json.loads((tmp_path / "r" / "run.json").read_text())["network"]["units"] == 1e30
    _, model = pdeinv.load_run(tmp_path / "r")
    want = predict(run.model, y[:5] * 1e30)  # the saved model's whitening is folded: float32 rounding apart
    np.testing.assert_allclose(predict(model, y[:5] * 1e30), want, rtol=0, atol=1e-6 * np.abs(want).max())
    assert np.isfinite(predict(model, torch.tensor(y[:5] * 1e30))).all()


def test_nonlinear_physics_refuses_data_in_other_units():
    p = pdeinv.load_problem("allen_cahn_1d", n=16)
    x, y = p.sample(40, seed=0)
    with pytest.raises(ValueError, match=r"data holds values up to .*physics is nonlinear.*divide by 1e\+30"):
        Trainer(p, "sip", data=y * 1e30, steps=1, n_test=8, progress=False)


def test_cli_train_and_predict_in_the_files_units(pairs, tmp_path, capsys):
    x, y = pairs
    np.savez(tmp_path / "d.npz", x=x * 1e-100, y=y * 1e-100)
    run, out = tmp_path / "run", tmp_path / "p.npz"
    data = str(tmp_path / "d.npz")
    assert main(["train", "heat_1d", "--set", "n=16", "--set", "noise=0.01", "--data", data, "--steps", "3",
                 "--n-test", "40", "--out", str(run), "-q"]) == 0
    assert main(["predict", str(run), "--data", str(tmp_path / "d.npz"), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["train", "heat_1d", "--set", "n=16", "--data", data, "--explain"]) == 0
    assert "units     the data divided by 1e-100 for training" in capsys.readouterr().out
    p = np.load(out)
    err = np.linalg.norm(p["x"] - x * 1e-100, axis=1) / np.linalg.norm(x * 1e-100, axis=1)
    assert np.median(err) < 0.5 and np.all(p["std"] > 0) and np.all(p["std"] < 1e-98)


@pytest.mark.parametrize("c", [1e200, 1e-250])
def test_beyond_float64s_squares_train_predict_and_classical_answer_as_in_the_scenes_units(pairs, tmp_path,
                                                                                          capsys, c):
    """Before, magnitudes beyond 1e±150 were refused (their squares leave float64): every check, error and
    solve now works on the rows divided by a power of ten, and the numbers match the scene's units."""
    x, y = pairs
    figures = {}
    for s in (1.0, c):
        data, run = str(tmp_path / f"d{s:g}.npz"), tmp_path / f"run{s:g}"
        np.savez(data, x=x * s, y=y * s)
        base = ["--set", "n=16", "--set", "noise=0.01", "--data", data]
        train = ["train", "heat_1d", *base, "--steps", "3", "--n-test", "40", "--out", str(run), "-q"]
        assert main(train) == 0
        assert main(["predict", str(run), "--data", data, "--out", str(tmp_path / f"p{s:g}.npz")]) == 0
        assert main(["classical", "heat_1d", *base, "--out", str(tmp_path / f"c{s:g}.json")]) == 0
        capsys.readouterr()
        metrics = json.loads((run / "metrics.json").read_text())
        classical = json.loads((tmp_path / f"c{s:g}.json").read_text())
        p = np.load(tmp_path / f"p{s:g}.npz")
        figures[s] = (metrics["x_err"], classical["tikhonov_morozov"]["x_err"],
                      classical["gaussian_posterior"]["width_90"] / s, float(np.mean(p["std"])) / s)
    np.testing.assert_allclose(figures[c], figures[1.0], rtol=1e-5)
