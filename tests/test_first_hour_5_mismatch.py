"""Mismatched data is loud (issue 48, item 5): a file whose model mismatch ``mean ‖P x − y‖/‖y‖`` exceeds
what its noise explains by the factor that makes ``pdeinv classical`` exit 3
(:func:`pdeinv.training.data.beyond_noise`) is refused by ``train`` and ``predict`` with exit 3 and one line
naming the figure and the limit, before anything is written; ``--accept-bad`` keeps the run (with the
warning). A mismatch above what the noise explains but below that limit trains with the warning. One
threshold: moving it moves all three commands. ``classical`` on observations with no signal says so
with exit 3."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.training import data as data_module
from pdeinv.training.data import model_mismatch

pytestmark = pytest.mark.usefixtures("one_thread")

SCENE = ["--set", "n=16", "--set", "steps=10"]
TRAIN = ["--steps", "3", "--prior-fit", "0", "-q", "--n-test", "8", "--export-samples", "0"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """heat_1d (n = 16, 10 steps) draws: the scene's own, another κ's (mismatch 1.7), y scaled by 999
    (mismatch 0.999), 3 % noise declared as 1 % (mismatch 0.03: above 1.1 × 1 %, below the limit 0.05),
    and pure noise without x."""
    folder = tmp_path_factory.mktemp("mismatch")
    heat = pdeinv.load_problem("heat_1d", n=16, steps=10)
    x, y = heat.sample(40, 0)
    xk, yk = pdeinv.load_problem("heat_1d", n=16, steps=10, kappa=0.05).sample(40, 0)
    rng = np.random.default_rng(0)
    noisy = y + 0.03 * np.sqrt((y**2).mean(1, keepdims=True)) * rng.standard_normal(y.shape)
    np.savez(folder / "good.npz", x=x, y=y)
    np.savez(folder / "kappa.npz", x=xk, y=yk)
    np.savez(folder / "scaled.npz", x=x, y=999 * y)
    np.savez(folder / "within.npz", x=x, y=noisy, noise=0.01)
    np.savez(folder / "noise.npz", y=rng.standard_normal(y.shape))
    return folder


@pytest.fixture(scope="module")
def run(files, tmp_path_factory):
    """A heat_1d run trained on the scene's own file (noise 0)."""
    out = tmp_path_factory.mktemp("runs") / "good"
    code = main(["train", "heat_1d", *SCENE, *TRAIN, "--data", str(files / "good.npz"), "--out", str(out)])
    assert code == 0
    return out


def _mismatch(files, name: str) -> float:
    with np.load(files / f"{name}.npz") as f:
        return model_mismatch(pdeinv.load_problem("heat_1d", n=16, steps=10).operator, f["x"], f["y"])


def _snapshot(folder) -> dict:
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_the_files_are_what_the_tests_say(files):
    assert _mismatch(files, "good") < 1e-12
    assert _mismatch(files, "kappa") > 1 and 0.99 < _mismatch(files, "scaled") < 1
    assert 0.011 < _mismatch(files, "within") < 0.05


@pytest.mark.parametrize("name", ["kappa", "scaled"])
def test_train_refuses_a_mismatch_its_noise_cannot_explain(files, tmp_path, capsys, name):
    before = _snapshot(files)
    out = tmp_path / "run"
    code = main(["train", "heat_1d", *SCENE, *TRAIN, "--data", str(files / f"{name}.npz"), "--out", str(out)])
    line = _one_line(capsys.readouterr().err)
    assert code == 3, line
    assert line.startswith("pdeinv train: error: --data ")
    assert f"{_mismatch(files, name):.3g}" in line and "0.05" in line and "--accept-bad" in line, line
    assert not out.exists()  # refused before anything is written
    assert _snapshot(files) == before


def test_train_with_accept_bad_trains_with_the_warning(files, tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["train", "heat_1d", *SCENE, *TRAIN, "--data", str(files / "kappa.npz"), "--out", str(out),
                 "--accept-bad"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"differ from this problem's P x by {_mismatch(files, 'kappa'):.3g}" in err
    assert "Traceback" not in err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["data"]["model_mismatch"] == pytest.approx(_mismatch(files, "kappa"))


def test_train_below_the_limit_warns_and_trains(files, tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["train", "heat_1d", *SCENE, *TRAIN, "--data", str(files / "within.npz"), "--out", str(out)])
    err = capsys.readouterr().err
    assert "more than its noise level 0.01 explains" in err and "trains on it anyway" not in err, err
    assert (out / "metrics.json").exists()  # trained (3 steps on 32 rows: its verdict is its own, code 3)
    assert code in (0, 3) and "Traceback" not in err


def test_predict_refuses_a_mismatch_beyond_the_limit(files, run, tmp_path, capsys):
    before = _snapshot(run)
    pred = tmp_path / "pred.npz"
    code = main(["predict", str(run), "--data", str(files / "kappa.npz"), "--out", str(pred)])
    line = _one_line(capsys.readouterr().err)
    assert code == 3, line
    assert line.startswith("pdeinv predict: error: --data ")
    assert f"{_mismatch(files, 'kappa'):.3g}" in line and "--accept-bad" in line, line
    assert not pred.exists() and _snapshot(run) == before
    code = main(["predict", str(run), "--data", str(files / "kappa.npz"), "--out", str(pred), "--accept-bad"])
    line = _one_line(capsys.readouterr().err)
    assert code == 0 and "warning" in line and f"{_mismatch(files, 'kappa'):.3g}" in line, line
    assert np.load(pred)["x"].shape == (40, 15)


def test_predict_of_its_own_physics_says_nothing(files, run, tmp_path, capsys):
    pred = tmp_path / "p.npz"
    assert main(["predict", str(run), "--data", str(files / "good.npz"), "--out", str(pred)]) == 0
    assert capsys.readouterr().err == ""


def test_classical_train_and_predict_share_one_threshold(files, run, tmp_path, capsys, monkeypatch):
    """Raising the one limit (:data:`pdeinv.training.data.MISMATCH_FLOOR`) lets every command through."""
    kappa = str(files / "kappa.npz")
    assert main(["classical", "heat_1d", *SCENE, "--data", kappa]) == 3
    assert "far above the noise level" in capsys.readouterr().err
    monkeypatch.setattr(data_module, "MISMATCH_FLOOR", 10.0)
    assert main(["classical", "heat_1d", *SCENE, "--data", kappa]) == 0
    assert main(["train", "heat_1d", *SCENE, *TRAIN, "--data", kappa, "--out", str(tmp_path / "r")]) == 0
    assert main(["predict", str(run), "--data", kappa, "--out", str(tmp_path / "p.npz")]) == 0
    err = capsys.readouterr().err
    assert "error" not in err and "Traceback" not in err, err


def test_classical_on_pure_noise_says_there_is_no_signal(files, tmp_path, capsys):
    out = tmp_path / "c.json"
    code = main(["classical", "heat_1d", *SCENE, "--data", str(files / "noise.npz"), "--out", str(out)])
    line = _one_line(capsys.readouterr().err)
    assert code == 3, line
    assert line.startswith("pdeinv classical: error: ") and "no signal" in line and "--accept-bad" in line
    assert str(files / "noise.npz") in line
    assert not out.exists()
    assert main(["classical", "heat_1d", *SCENE, "--data", str(files / "noise.npz"), "--accept-bad"]) == 0
    line = _one_line(capsys.readouterr().err)
    assert "warning" in line and "no signal" in line


def test_train_on_pure_noise_says_there_is_no_signal(tmp_path, capsys):
    """No declared level and y that are noise all through: exit 3 and one line (never "noise=inf is not
    allowed"), nothing written; a noisy file with a signal (level 0.3) still trains."""
    np.savez(tmp_path / "noise.npz", y=np.random.default_rng(0).standard_normal((300, 63)))
    code = main(["train", "heat_1d", *TRAIN, "--data", str(tmp_path / "noise.npz"),
                 "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 3 and "shows no signal" in err and "inf" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r").exists()
    problem = pdeinv.load_problem("heat_1d", noise=0.3)
    x, y = problem.sample(300, seed=3)
    np.savez(tmp_path / "noisy.npz", y=y)
    assert main(["train", "heat_1d", *TRAIN, "--data", str(tmp_path / "noisy.npz"),
                 "--out", str(tmp_path / "s")]) == 0
    capsys.readouterr()


@pytest.mark.parametrize("name", ["noise", "zeros"])
def test_predict_on_observations_with_no_signal_says_so(files, run, tmp_path, capsys, name):
    """Pure noise or all-zero observations (of any x) are no run's physics: exit 3 and one line, the check of
    train and classical (:func:`pdeinv.training.data.no_signal`); ``--accept-bad`` predicts with a warning."""
    data = tmp_path / f"{name}.npz"
    if name == "zeros":
        np.savez(data, y=np.zeros((40, 15)), x=np.zeros((40, 15)))
    else:
        data = files / "noise.npz"
    pred = tmp_path / "pred.npz"
    code = main(["predict", str(run), "--data", str(data), "--out", str(pred)])
    line = _one_line(capsys.readouterr().err)
    assert code == 3, line
    assert line.startswith(f"pdeinv predict: error: --data {str(data)!r} shows no signal"), line
    assert "--accept-bad" in line
    assert not pred.exists()
    assert main(["predict", str(run), "--data", str(data), "--out", str(pred), "--accept-bad"]) == 0
    assert "warning" in _one_line(capsys.readouterr().err) and pred.exists()


def test_a_few_valid_rows_are_never_called_signal_free():
    """The noise reading takes the median singular value as noise, which a handful of rows cannot show: six
    noise-free wave_2d observations can read 9.6 (above the 2.18 of "no signal"); below NO_SIGNAL_ROWS the
    check says nothing, and pure noise of that many rows is still refused."""
    from pdeinv.training.data import NO_SIGNAL_ROWS, no_signal, read_noise

    wave = pdeinv.load_problem("wave_2d", n=16)
    _, y = wave.sample(6, seed=600)
    assert no_signal(read_noise(y, wave.operator), len(y)) is None
    noise = np.random.default_rng(0).standard_normal((NO_SIGNAL_ROWS, wave.operator.n_out))
    assert no_signal(read_noise(noise, wave.operator), len(noise)) is not None
