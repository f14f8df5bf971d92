"""Results that cannot be right end loudly (issue 36): the classical solves of another physics' data,
an empty ``--data``, one observation repeated; repeats among distinct rows are named."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.training.data import own_data


@pytest.fixture
def files(tmp_path):
    """heat_1d (n = 16) draws at κ = 0.002 (the problem's default is 0.01), with and without x."""
    x, y = pdeinv.load_problem("heat_1d", n=16, kappa=0.002).sample(64, 1)
    np.savez(tmp_path / "other.npz", x=x, y=y)
    x, y = pdeinv.load_problem("heat_1d", n=16).sample(64, 1)
    np.savez(tmp_path / "same.npz", x=x, y=y)
    return tmp_path


def test_classical_refuses_data_of_other_settings_and_passes_its_own(files, capsys):
    run = ["classical", "heat_1d", "--set", "n=16", "--data"]
    assert main([*run, str(files / "same.npz")]) == 0
    assert "error" not in capsys.readouterr().err
    out = files / "c.json"
    assert main([*run, str(files / "other.npz"), "--out", str(out)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "far above the noise level" in err[0] and "--accept-bad" in err[0]
    assert "differ from this problem's P x" in json.loads(out.read_text())["failed"]  # written anyway
    assert main([*run, str(files / "other.npz"), "--accept-bad"]) == 0
    assert "warning" in capsys.readouterr().err


def test_an_empty_data_path_is_refused(tmp_path, capsys):
    assert main(["train", "--prior-fit", "0", "heat_1d", "--data", "", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "--data '' names no file" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_one_observation_repeated_is_refused_and_repeats_are_named():
    p = pdeinv.load_problem("heat_1d", n=16)
    y = p.sample(40, 0)[1]
    with pytest.raises(ValueError, match="all 40 rows are the same observation"):
        own_data(p, np.repeat(y[:1], 40, axis=0), None, 8)
    with pytest.warns(RuntimeWarning, match="3 of 40 rows repeat an earlier row"):
        own_data(p, np.vstack([y[:37], y[:3]]), None, 8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        own_data(p, y, None, 8, warn=False)


def test_a_picture_of_many_samples_is_capped(tmp_path):
    """fields.png draws at most PNG_SAMPLES rows (100 000 exported samples once made a 35 712 px tall
    picture in 148 s); the title names the cap."""
    import matplotlib.image as mpimg

    from pdeinv.io.plots import PNG_SAMPLES, save_fields_png

    p = pdeinv.load_problem("heat_1d", n=16)
    x = p.sample(40, 0)[0]
    v = p.disc.vertex_values(x)
    mesh = p.disc.basis.mesh
    few = save_fields_png(tmp_path / "few.png", mesh.p.T, mesh.t.T, {"x_true": v[:PNG_SAMPLES],
                                                                    "x_pred": v[:PNG_SAMPLES]})
    many = save_fields_png(tmp_path / "many.png", mesh.p.T, mesh.t.T, {"x_true": v, "x_pred": v})
    assert mpimg.imread(many).shape[0] <= 1.2 * mpimg.imread(few).shape[0]
