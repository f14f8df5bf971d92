"""Bad and odd inputs of the seventh round (issue 48): a user's sampler of any array-like, a posterior
file checked, sample counts and noise levels in range, the rules' preset batch capped instead of refused,
a module that ignores its overrides, the nonlinear scenes' stress sweeps, and messages in the user's
words. Each case failed (a traceback, a wrong exit 0 or a misleading line) on the code before."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.cli import main

SMALL = ["--threads", "1", "-q", "--steps", "2", "--prior-fit", "0", "--n-train", "64", "--n-test", "16"]

SAMPLER = """
import numpy as np
from pdeinv import mesh, scenes
from pdeinv import settings as s
import pdeinv
SETTINGS = {{**scenes.HEAT, "n": (16, s.positive_int)}}
def make(**o):
    cfg = s.resolve(SETTINGS, o, "mine")
    p = scenes.heat("mine", mesh.interval(cfg["n"]), cfg)
    N = p.N
    def sampler(n, rng):
{body}
    return pdeinv.Problem("mine", p.disc, p.operator, sampler, settings=cfg, noise=cfg["noise"],
                          inverse_simulator=p.inverse_simulator)
"""


def _module(tmp_path, body: str):
    path = tmp_path / "mine.py"
    path.write_text(SAMPLER.format(body=body))
    return path


def _one_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("body", [
    "        return rng.standard_normal((n, N)).tolist()",
    "        import torch\n        return torch.randn(n, N, dtype=torch.float64)",
    "        return (10 * rng.standard_normal((n, N))).astype(int)",
])
def test_a_sampler_may_return_any_array_of_numbers(tmp_path, body):
    p = pdeinv.load_problem(_module(tmp_path, body))
    x, y = p.sample(8)
    assert x.dtype == np.float64 and x.shape == (8, p.N) and np.isfinite(y).all()


@pytest.mark.parametrize("body, says", [
    ("        return None",
     "pdeinv train: error: problem 'mine': its sampler returned NoneType; expected a numpy array of shape"),
    ("        raise ValueError('sampler boom')",
     "mine.py, line 12, in sampler: ValueError: sampler boom (the sampler of problem 'mine')"),
    ("        return np.full((n, N), 'a')", "its sampler returned an array of <U1"),
])
def test_a_sampler_that_fails_is_one_line(tmp_path, capsys, body, says):
    module = _module(tmp_path, body)
    assert main(["train", str(module), *SMALL, "--out", str(tmp_path / "r")]) == 2
    assert says in _one_error(capsys)


def test_a_module_that_ignores_an_override_is_refused(tmp_path, capsys):
    path = tmp_path / "ignores.py"
    path.write_text("from pdeinv import mesh, scenes\nfrom pdeinv import settings as s\n"
                    "SETTINGS = {**scenes.HEAT, 'n': (16, s.positive_int)}\n"
                    "def make(**o):\n"
                    "    cfg = s.resolve(SETTINGS, {}, 'ignores')\n"
                    "    return scenes.heat('ignores', mesh.interval(16), cfg)\n")
    assert main(["train", str(path), "--set", "n=8", *SMALL, "--out", str(tmp_path / "r")]) == 2
    assert "make(n='8') returned a Problem whose settings have n=16: make ignores the override" in \
        _one_error(capsys)
    assert not (tmp_path / "r").exists()  # a refused run leaves no folder it made


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A small heat_1d run with a posterior, and a file of its observations."""
    tmp = tmp_path_factory.mktemp("run")
    assert main(["train", "heat_1d", *SMALL, "--out", str(tmp / "r")]) == 0
    p = pdeinv.load_problem("heat_1d")
    x, y = p.sample(20, seed=3)
    np.savez(tmp / "obs.npz", x=x, y=y)
    return tmp


@pytest.mark.parametrize("edit, says", [
    (lambda f: {**f, "quantiles": f["quantiles"][::-1]}, "its 'quantiles' is not 4001 finite non-decreasing"),
    (lambda f: {**f, "scale": np.full_like(f["scale"], np.nan)}, "its 'scale' is not a positive finite"),
    (lambda f: {**f, "residuals": f["residuals"][:0]}, "its 'residuals' is not at least one finite row"),
])
def test_an_edited_posterior_file_is_refused(run, tmp_path, capsys, edit, says):
    import shutil

    folder = tmp_path / "r"
    shutil.copytree(run / "r", folder)
    with np.load(folder / "posterior.npz") as f:
        arrays = edit(dict(f))
    np.savez(folder / "posterior.npz", **arrays)
    code = main(["predict", str(folder), "--data", str(run / "obs.npz"), "--out", str(tmp_path / "p.npz")])
    assert code == 2 and says in _one_error(capsys)
    assert not (tmp_path / "p.npz").exists()


def test_predict_samples_at_most_the_kept_residuals_and_its_level_as_given(run, tmp_path, capsys):
    kept = len(pdeinv.io.runs.load_posterior(run / "r").residuals)
    out = tmp_path / "p.npz"
    args = ["predict", str(run / "r"), "--data", str(run / "obs.npz"), "--out", str(out)]
    assert main([*args, "--samples", str(kept + 1)]) == 2
    assert f"keeps {kept} residuals and each sample is one of them; expected at most {kept}" in \
        _one_error(capsys)
    assert main([*args, "--seed", "-1"]) == 2 and "--seed -1 is not allowed" in _one_error(capsys)
    assert main([*args, "--level", "0.999"]) == 0
    assert "99.9 % intervals" in capsys.readouterr().out


def test_a_declared_noise_level_the_files_x_contradict_is_refused(tmp_path, capsys):
    """noise=1e6 declared on noise-free data trained with exit 0; a level its rows do show trains."""
    p = pdeinv.load_problem("heat_1d")
    x, y = p.sample(80, seed=1)
    args = ["train", "heat_1d", "--threads", "1", "-q", "--steps", "2", "--prior-fit", "0", "--n-test", "16"]
    np.savez(tmp_path / "loud.npz", x=x, y=y, noise=1e6)
    assert main([*args, "--data", str(tmp_path / "loud.npz"), "--out", str(tmp_path / "r")]) == 3
    assert "it declares noise=1e+06, but its y differ from P x by" in _one_error(capsys)
    assert not (tmp_path / "r").exists()  # a refused run leaves no folder it made
    noisy = p.sample(80, seed=1)[1] + 0.05 * np.sqrt(np.mean(y**2, axis=1, keepdims=True)) * \
        np.random.default_rng(0).standard_normal(y.shape)
    np.savez(tmp_path / "noisy.npz", x=x, y=noisy, noise=0.05)
    assert main([*args, "--data", str(tmp_path / "noisy.npz"), "--out", str(tmp_path / "n")]) == 0
    capsys.readouterr()
    assert main(["classical", "heat_1d", "--data", str(tmp_path / "loud.npz")]) == 3
    assert "the file's noise level: it declares noise=1e+06" in _one_error(capsys)


def test_a_presets_batch_is_capped_at_the_training_rows_and_a_given_one_is_checked(tmp_path, capsys):
    args = ["train", "heat_1d", "--method", "gd", "--threads", "1", "-q", "--steps", "2", "--prior-fit", "0"]
    assert main([*args, "--n-train", "16", "--out", str(tmp_path / "a")]) == 0  # gd's 32 rows: all 16
    assert json.loads((tmp_path / "a" / "metrics.json").read_text())["x_err"] < 1
    capsys.readouterr()
    assert main([*args, "--n-train", "16", "--batch-size", "32", "--explain"]) == 2
    assert "--batch-size 32 is larger than --n-train 16" in _one_error(capsys)
    p = pdeinv.load_problem("heat_1d")
    y = p.sample(40, seed=2)[1]
    with pytest.raises(ValueError, match=r"^n_train=16 does not apply with data="):
        pdeinv.Trainer(p, "gd", data=y, n_train=16, steps=1, progress=False)


def test_api_arguments_are_named(capsys):
    p = pdeinv.load_problem("heat_1d", n=16)
    with pytest.raises(TypeError, match=r"^dtype=torch.float16 is not allowed; expected None, torch.float32"):
        pdeinv.Trainer(p, "sip", dtype=torch.float16, steps=1)
    with pytest.raises(ValueError, match=r"^model does not take this problem's 15 observations per row "
                                         r"\(this Whitening takes 31 observations per row"):
        pdeinv.Trainer(p, "sip", model=pdeinv.load_problem("heat_1d", n=32).model(), steps=1)
    with pytest.raises(ValueError, match=r"^optimizer LBFGS is not allowed: its step needs a closure"):
        pdeinv.train(p, pdeinv.GD(optimizer=torch.optim.LBFGS), steps=1, n_train=16, n_test=4, prior=None,
                     calibration=None, progress=False)
    from pdeinv.io.plots import plot_prediction

    x = p.sample(2)[0]
    with pytest.raises(ValueError, match=r"^samples=-1 is not allowed; the file holds samples 0..1"):
        plot_prediction(p, x, x, samples=-1)
    with pytest.raises(TypeError, match=r"^samples='a' is not allowed; expected None \(all\), an index"):
        plot_prediction(p, x, x, samples="a")


def test_resume_with_other_data_settings_names_the_flag(tmp_path, capsys):
    out = str(tmp_path / "r")
    assert main(["train", "heat_1d", *SMALL, "--out", out]) == 0
    capsys.readouterr()
    assert main(["train", "heat_1d", "--threads", "1", "-q", "--steps", "4", "--prior-fit", "0",
                 "--n-train", "64", "--n-test", "16", "--seed", "1", "--resume", "--out", out]) == 2
    assert "was written with other data settings: seed=0 (checkpoint) vs 1 (this run) (--seed)" in \
        _one_error(capsys)
    assert main(["train", "heat_1d", "--threads", "1", "-q", "--steps", "4", "--prior-fit", "0",
                 "--n-train", "64", "--n-test", "16", "--net", "modal", "--resume", "--out", out]) == 2
    line = _one_error(capsys)
    assert "network; this run's is a" in line and len(line) < 300, line


def test_a_scene_that_observes_nothing_says_so_without_numpy_warnings(tmp_path, capsys):
    assert main(["train", "heat_1d", "--set", "kappa=1e100", *SMALL, "--out", str(tmp_path / "r")]) == 2
    err = _one_error(capsys)
    assert "the training observations do not vary (zero covariance)" in err and "warning" not in err
    assert not (tmp_path / "r").exists()  # refused after its checkpoint's folder was made: removed


def test_stress_on_a_nonlinear_scene_builds_only_the_cases_it_can_run(tmp_path, capsys):
    out = str(tmp_path / "s")
    assert main(["stress", "allen_cahn_1d", "--quick", "--set", "n=8", "--out", out, "-q"]) == 0
    record = json.loads((tmp_path / "s" / "stress.json").read_text())
    outcomes = [c["outcome"] for c in record["cases"]]
    assert "error" not in outcomes and outcomes.count("ok") >= 12, record["counts"]
    matrix_only = [c for c in record["cases"] if c["sweep"] in ("noise", "explicit") or "alpha" in c["sweep"]]
    assert not matrix_only
    assert "FailedRun" not in capsys.readouterr().err
