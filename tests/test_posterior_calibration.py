"""The calibration stage: conformal coverage on held-out rows, whatever the network; SBC; files; bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.cli import main
from pdeinv.posterior import Calibration, CalibrationStage, predictive
from pdeinv.posterior.diagnostics import report
from pdeinv.training.trainset import CALIBRATION_DATA, seed_stream


def draws(problem, seed=0):
    """The trainer's calibration rows (its seed stream)."""
    return lambda n: problem.sample(n, seed_stream(seed, CALIBRATION_DATA))


@pytest.fixture(scope="module")
def heat_1d():
    """The real default (SIP, its preset, the prior and calibration stages) on heat_1d with 500 test rows."""
    problem = pdeinv.load_problem("heat_1d", prior="grf")
    return problem, pdeinv.train(problem, "sip", n_test=500, progress=False)


def test_default_run_is_calibrated(heat_1d):
    """CI-sized coverage regression: 90 % intervals and the 90 % ball cover 86–94 % of 500 held-out rows;
    the samples' ranks pass SBC."""
    _, result = heat_1d
    test = result.metrics["posterior"]
    assert result.metrics["stages"][-1]["name"] == "calibration"
    assert test["rows"] == 500
    assert 0.86 <= test["coverage_90"] <= 0.94
    assert 0.45 <= test["coverage_50"] <= 0.55
    assert 0.92 <= test["coverage_95"] <= 0.98
    assert 0.86 <= test["ball_coverage_90"] <= 0.94
    assert test["sbc_p_node"] > 0.01 and test["sbc_p_mean"] > 0.01


class Shrunk(torch.nn.Module):
    """A deliberately mis-scaled network: ``factor · f(y)``."""

    def __init__(self, inner, factor):
        super().__init__()
        self.inner, self.factor = inner, factor

    def forward(self, y):
        return self.factor * self.inner(y)


@pytest.mark.parametrize("factor", [0.5, 1.5])
def test_conformal_coverage_holds_for_a_mis_scaled_network(heat_1d, factor):
    """Intervals fitted on the mis-scaled network's own residuals still cover 90 % (conformal), while
    the good network's intervals around the mis-scaled mean do not."""
    problem, result = heat_1d
    bad = Shrunk(result.model, factor)
    test = result.metrics  # the same test rows the trainer drew
    x, y = pdeinv.Trainer(problem, "sip", n_test=500, progress=False).held_out()
    cal, info = CalibrationStage().run(problem, bad, None, 0, (x, y), draws(problem))
    assert 0.86 <= info["test"]["coverage_90"] <= 0.94
    mean = predictive(bad, cal, y)["x"]
    wrong = report(result.posterior, mean, x, problem.disc.M)
    assert wrong["coverage_90"] < 0.8, (wrong, test["posterior"])
    assert info["test"]["width_90"] > test["posterior"]["width_90"]  # honest: a worse mean, wider intervals


def test_calibration_on_known_residuals():
    """Heavy-tailed residuals with per-node scales: coverage at any level, ball and std as designed."""
    rng = np.random.default_rng(0)
    N = 40
    scales = np.linspace(0.1, 2.0, N)

    def draw(n):
        return scales * rng.standard_t(5, size=(n, N))

    cal = Calibration.fit(draw(3000), draw(3000))
    fresh = draw(4000)
    for level in (0.5, 0.8, 0.9, 0.99):
        lo, hi = cal.interval(np.zeros((1, N)), level)
        assert abs(np.mean((lo <= fresh) & (fresh <= hi)) - level) < 0.01
    assert abs(np.mean(np.linalg.norm(fresh, axis=1) <= cal.ball_radius(0.9)) - 0.9) < 0.02
    assert np.allclose(cal.std / scales, np.sqrt(5 / 3), rtol=0.1)  # t₅'s std, per node
    draws = cal.samples(np.zeros((2, N)), 5000, seed=1)  # resampled from 256 kept rows
    assert draws.shape == (2, 5000, N)
    q95 = np.quantile(draws, 0.95, axis=1) / scales  # t₅'s 95 % quantile: 2.015
    assert np.allclose(np.median(q95, axis=1), 2.015, rtol=0.1)


def test_sbc_in_chunks_is_the_sbc_of_all_samples(monkeypatch):
    """The SBC draws are made a chunk of rows at a time; the ranks are those of ``samples`` at once."""
    from pdeinv.posterior import diagnostics

    rng = np.random.default_rng(3)
    N, B = 30, 70
    cal = Calibration.fit(rng.standard_normal((500, N)), rng.standard_normal((500, N)))
    mean, x = rng.standard_normal((B, N)), rng.standard_normal((B, N))
    chunked = report(cal, mean, x, seed=4)
    monkeypatch.setattr(diagnostics, "SBC_ROWS", B)
    assert report(cal, mean, x, seed=4) == chunked
    draws = cal.samples(mean, diagnostics.SBC_SAMPLES, seed=5)  # the stream the report draws from
    node = np.random.default_rng(4).integers(N, size=B)
    r = np.random.default_rng(4)
    r.integers(N, size=B)
    ranks = diagnostics._ranks(x[np.arange(B), node], draws[np.arange(B), :, node], r)
    assert chunked["sbc_p_node"] == diagnostics._ks(ranks)


def test_default_test_rows_are_enough_for_sbc():
    """256 drawn test rows by default (the SBC's ≥ 200), the last 128 rows of a user's file."""
    from pdeinv.training.trainset import N_TEST, test_count

    assert N_TEST >= 200 and test_count(None, False) == N_TEST and test_count(None, True) == 128
    assert pdeinv.Trainer("heat_1d", "sip", progress=False).n_test == N_TEST
    x, y = pdeinv.load_problem("heat_1d").sample(300, 0)
    assert pdeinv.Trainer("heat_1d", "sip", data=y, data_x=x, progress=False).n_test == 128
    assert pdeinv.Trainer("heat_1d", "sip", n_test=7, progress=False).n_test == 7


def test_bad_levels():
    cal = Calibration.fit(np.ones((4, 3)), np.ones((4, 3)))
    for level in (0, 1, 1.5, -0.1):
        with pytest.raises(ValueError, match=f"level={level!r}"):
            cal.interval(np.zeros((1, 3)), level)
    with pytest.raises(TypeError, match="level='high'"):
        cal.interval(np.zeros((1, 3)), "high")
    with pytest.raises(ValueError, match="samples=-1"):
        predictive(torch.nn.Identity(), cal, np.zeros((1, 3)), samples=-1)
    with pytest.raises(ValueError, match="CalibrationStage.rows=2"):
        CalibrationStage(rows=2)


def test_deterministic(heat_1d):
    problem, result = heat_1d
    x, y = pdeinv.Trainer(problem, "sip", n_test=500, progress=False).held_out()
    again, _ = CalibrationStage().run(problem, result.model, None, 0, (x, y), draws(problem))
    assert again.to_bytes() == result.posterior.to_bytes()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("calibrated")
    argv = ["train", "heat_1d", "--steps", "5", "-q", "--export-samples", "0", "--out", str(d / "run")]
    assert main(argv) == 0
    problem = pdeinv.load_problem("heat_1d")
    x, y = problem.sample(200, seed=77)
    np.savez(d / "obs.npz", x=x, y=y)
    return d


def test_predict_writes_intervals_and_samples(run, capsys):
    assert main(["predict", str(run / "run"), "--data", str(run / "obs.npz"), "--out", str(run / "p.npz"),
                 "--samples", "4", "--level", "0.8"]) == 0
    assert "80 % intervals cover" in capsys.readouterr().out
    with np.load(run / "p.npz") as f:
        assert f["samples"].shape == (200, 4, 63)
        assert (f["lo"] <= f["x"]).all() and (f["x"] <= f["hi"]).all() and (f["std"] > 0).all()
        x = np.load(run / "obs.npz")["x"]
        assert 0.7 <= np.mean((f["lo"] <= x) & (x <= f["hi"])) <= 0.9
    metrics = json.loads((run / "run" / "metrics.json").read_text())
    assert {"coverage_90", "ball_coverage_90", "sbc_p_node", "width_90"} <= set(metrics["posterior"])


@pytest.mark.parametrize("argv, needle", [
    (["--level", "1.5"], "--level 1.5 is not allowed"),
    (["--level", "0"], "--level 0 is not allowed"),
    (["--samples", "0"], "--samples 0 is not allowed"),
])
def test_predict_bad_input(run, capsys, argv, needle):
    out = run / "bad.npz"
    assert main(["predict", str(run / "run"), "--data", str(run / "obs.npz"), "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_predict_without_posterior(run, capsys):
    problem = pdeinv.load_problem("heat_1d")
    result = pdeinv.train(problem, "sip", steps=2, calibration=None, prior=None, progress=False)
    assert result.posterior is None and "posterior" not in result.metrics
    pdeinv.save_run(run / "bare", "heat_1d", model=result.model)
    argv = ["predict", str(run / "bare"), "--data", str(run / "obs.npz"), "--out", str(run / "q.npz")]
    assert main([*argv, "--samples", "3"]) == 2
    assert "has no calibrated posterior" in capsys.readouterr().err
    assert main(argv) == 0  # the mean alone
    with np.load(run / "q.npz") as f:
        assert set(f.files) == {"x"}


def test_fields_show_the_std_and_where_the_truth_falls_outside(run):
    from pdeinv.io.export import read_fields

    out = run / "fields.vtu"
    assert main(["predict", str(run / "run"), "--data", str(run / "obs.npz"), "--out", str(run / "f.npz"),
                 "--vtu", str(out)]) == 0
    _, _, fields = read_fields(out)
    assert {"x_std", "x_lo", "x_hi", "x_outside"} <= set(fields)
    inside = fields["x_outside"] == 0
    assert 0.8 < inside.mean() < 0.97 and set(np.unique(fields["x_outside"])) <= {-1.0, 0.0, 1.0}
    assert (fields["x_true"][~inside] < fields["x_lo"][~inside]).sum() + \
        (fields["x_true"][~inside] > fields["x_hi"][~inside]).sum() == (~inside).sum()


def test_own_data_with_x_is_calibrated_on_its_own_held_out_rows():
    """A data file with x (drawn from another prior than the scene's: grf, not its bumps) is calibrated on
    its own rows: a fifth of those before the test rows, held out before any stage, never the scene's
    sampler; the 90 % intervals then cover 86–94 % of 500 test rows. A file without x gets no posterior."""
    problem = pdeinv.load_problem("heat_1d", prior="grf")
    x, y = problem.sample(3000, 7)
    scene = pdeinv.load_problem("heat_1d")  # its own prior (bumps) is not the file's
    result = pdeinv.train(scene, "sip", data=y, data_x=x, n_test=500, progress=False)
    rows = result.metrics["data"]["rows"]
    assert rows["calibration"] == [2000, 2500] and rows["train"] == [0, 2000] and rows["test"] == [2500, 3000]
    stage = result.metrics["stages"][-1]
    assert stage["name"] == "calibration" and stage["rows"] == 500 and stage["source"] == "data"
    test = result.metrics["posterior"]
    assert test["rows"] == 500 and 0.86 <= test["coverage_90"] <= 0.94
    assert 0.86 <= test["ball_coverage_90"] <= 0.94
    bare = pdeinv.train(scene, "sip", data=y, n_test=500, steps=2, progress=False)
    assert "no x" in bare.metrics["stages"][-1]["skipped"] and "posterior" not in bare.metrics
