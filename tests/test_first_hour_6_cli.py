"""The first hour, round six (issue 48): what a fresh round of bad inputs found on the command line.
Observations in other units than the run's, rows in no one unit, a resumed run on the same y without
their x, a setting given back its listed default, an image format ``show`` cannot write, and a user's own
``bench.json``."""

from __future__ import annotations

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main

pytestmark = pytest.mark.usefixtures("one_thread")

SMALL = ["--set", "n=16", "--steps", "3", "--prior-fit", "0", "--n-train", "64", "--n-test", "16",
         "--threads", "1", "-q"]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A small heat_1d run and observations of its scene (``obs.npz``: y and x)."""
    d = tmp_path_factory.mktemp("round6")
    assert main(["train", "heat_1d", *SMALL, "--out", str(d / "run")]) == 0
    x, y = pdeinv.load_problem("heat_1d", n=16).sample(300, seed=5)
    np.savez(d / "obs.npz", y=y, x=x)
    return d


@pytest.mark.parametrize("scale", [1e300, 1e-200])
def test_predict_refuses_observations_in_other_units(run, tmp_path, capsys, scale):
    """The network never saw inputs 1e300 × its training data's (its output was NaN, exit 0)."""
    with np.load(run / "obs.npz") as f:
        np.savez(tmp_path / "far.npz", y=f["y"] * scale)
    out = tmp_path / "p.npz"
    argv = ["predict", str(run / "run"), "--data", str(tmp_path / "far.npz"), "--out", str(out), "-q"]
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert "other units than the run's" in err and "--accept-bad" in err and not out.exists()
    assert main(["predict", str(run / "run"), "--data", str(run / "obs.npz"), "--out", str(out), "-q"]) == 0


def test_rows_in_no_one_unit_are_refused(run, tmp_path, capsys):
    with np.load(run / "obs.npz") as f:
        y = f["y"].copy()
    y[::2] *= 1e-100
    y[1::2] *= 1e100
    np.savez(tmp_path / "mixed.npz", y=y)
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "3", "--prior-fit", "0", "--n-test", "16",
                 "--threads", "1", "-q", "--data", str(tmp_path / "mixed.npz"),
                 "--out", str(tmp_path / "r")]) == 2
    assert "not in one unit" in capsys.readouterr().err and not (tmp_path / "r" / "model.pt").exists()


def test_resume_refuses_the_same_y_without_their_x(run, tmp_path, capsys):
    """The file's x train the prior and calibration stages: without them it is other data."""
    with np.load(run / "obs.npz") as f:
        np.savez(tmp_path / "y_only.npz", y=f["y"])
    args = ["train", "heat_1d", "--set", "n=16", "--prior-fit", "0", "--n-test", "16", "--threads", "1", "-q",
            "--checkpoint-every", "1", "--out", str(tmp_path / "ck")]
    assert main([*args, "--steps", "2", "--data", str(run / "obs.npz")]) == 0
    assert main([*args, "--steps", "3", "--resume", "--data", str(tmp_path / "y_only.npz")]) == 2
    assert "(--data)" in capsys.readouterr().err


@pytest.mark.parametrize("scene, setting", [("heat_boxes", "kappa=None"), ("sine_gordon_1d", "steps=None")])
def test_a_setting_takes_back_its_listed_default(scene, setting, capsys):
    """`pdeinv problems` lists kappa=None: given back, it is that default, not "not a number"."""
    assert main(["train", scene, "--set", "n=16", "--set", setting, "--explain"]) == 0
    default = main(["train", scene, "--set", "n=16", "--explain"])
    text = capsys.readouterr().out.split("\n")
    assert default == 0 and text[0] == text[len(text) // 2]  # the same problem line both times


def test_show_names_the_image_formats_it_writes(run, tmp_path, capsys):
    assert main(["show", str(run / "run"), "--png", str(tmp_path / "f.npz")]) == 2
    assert "--png" in capsys.readouterr().err and not (tmp_path / "f.npz").exists()
    assert main(["show", str(run / "run"), "--png", str(tmp_path / "f.svg")]) == 0
    assert (tmp_path / "f.svg").is_file()
