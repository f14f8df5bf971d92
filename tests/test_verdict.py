"""A run that ends worse than predicting zero is never reported as a success (pdeinv.training.verdict)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
import torch
from stderr import said

import pdeinv
from pdeinv import nets
from pdeinv.cli import main
from pdeinv.methods import GD, sgd
from pdeinv.training.verdict import FailedRun, failure

pytestmark = pytest.mark.usefixtures("one_thread")

#: an MLP pushed by two large Adam steps: held-out x_err 1.91 on heat_1d (n=16), seed 0
BAD = ["--method", "adam", "--hidden", "16", "--lr", "0.1", "--steps", "2", "--export-samples", "0"]


def test_the_verdict_is_the_zero_prediction_and_without_x_the_unseen_test():
    """x_err ≥ 1 (the zero prediction scores exactly 1) or not finite fails; without x only the
    unseen-energy bound judges, and where it does not apply nothing fails."""
    assert failure(0.999, None, 10) is None
    assert "x_err is 1" in failure(1.0, None, 10) and failure(math.nan, None, 10)
    record = {"prediction": 3.0, "prior": 1.0, "seen": 4, "bound": 2.5}
    assert failure(0.5, record, 10) is None  # with x, x_err alone decides
    why = failure(None, record, 10)
    assert "unseen-energy test" in why and "6 directions" in why and "3×" in why
    assert failure(None, {**record, "prediction": 2.0}, 10) is None and failure(None, None, 10) is None


def test_the_physics_of_the_data_is_judged_with_and_without_x():
    """y_err ≥ 1 (the zero prediction's) fails with or without x; without x, predictions over 100×
    the prior's rms amplitude fail (no field of the prior explains the data); x_err is named first."""
    assert "y_err is 1.45" in failure(0.5, None, 10, y_err=1.45) and failure(None, None, 10, math.nan)
    assert failure(0.5, None, 10, y_err=0.999) is None
    assert "x_err" in failure(2.0, None, 10, y_err=1.5)
    assert "100× the prior" not in (failure(None, None, 10, 0.01, 99.0) or "")
    assert failure(None, None, 10, 0.01, 99.0) is None
    assert "1.6e+08× the prior's rms amplitude" in failure(None, None, 10, 0.01, 1.6e8)


def test_cli_data_of_another_physics_without_x_fails(tmp_path, capsys):
    """wave_1d observations fed to heat_1d: SIP fits them (y_err 0.006) with fields 1e8 times the
    prior's size; the run ends with exit 3 naming the amplitude, not exit 0 with garbage."""
    x, y = pdeinv.load_problem("wave_1d", n=16).sample(200, 3)
    np.savez(tmp_path / "wave.npz", y=y)
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--set", "n=16", "--data", str(tmp_path / "wave.npz"), "--n-test", "32",
                 "--export-samples", "0", "--out", str(tmp_path / "run")]) == 3
    err = capsys.readouterr().err
    assert "the prior's rms amplitude" in err and "another physics" in err
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["amplitude"] > 1e6 and "amplitude" in m["failed"]


def test_cli_a_run_worse_than_zero_ends_with_exit_3_and_keeps_its_files(tmp_path, capsys):
    """One line on stderr naming the figure and the way out, no traceback; every file written and the
    verdict in metrics.json. With --accept-bad: exit 0, a warning, the verdict still recorded."""
    run = tmp_path / "run"
    assert main(["train", "--prior-fit", "0", "heat_1d", "--set", "n=16", *BAD, "--out", str(run)]) == 3
    err = said(capsys.readouterr().err)
    assert len(err) == 1 and err[0].startswith("pdeinv train: error: the run failed: ")
    figure = re.search(r"the held-out x_err is (\d+\.\d+), at least 1", err[0])
    assert figure and float(figure.group(1)) > 1.5, err[0]
    assert "--accept-bad" in err[0] and "Traceback" not in err[0]
    for name in ("metrics.json", "model.pt", "run.json", "history.csv", "training.png"):
        assert (run / name).exists(), name
    m = json.loads((run / "metrics.json").read_text())
    assert m["x_err"] > 1 and "x_err" in m["failed"] and m["accept_bad"] is False
    kept = tmp_path / "kept"
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--set", "n=16", *BAD, "--accept-bad", "--out", str(kept)]) == 0
    err = said(capsys.readouterr().err)
    assert len(err) == 1 and err[0].startswith("pdeinv train: warning: the run failed") and "kept" in err[0]
    m = json.loads((kept / "metrics.json").read_text())
    assert "x_err" in m["failed"] and m["accept_bad"] is True


def test_cli_without_x_the_unseen_energy_test_ends_the_run(tmp_path, capsys):
    """A file with y only (heat_1d, κ = 0.2: 4 of 15 directions seen) cannot score x; the unseen-energy
    test stops the same bad run (exit 3, naming the test); a good run passes."""
    p = pdeinv.load_problem("heat_1d", n=16, kappa=0.2)
    np.savez(tmp_path / "y.npz", y=p.sample(200, 3)[1])
    base = ["train", "--prior-fit", "0",
            "heat_1d", "--set", "n=16", "--set", "kappa=0.2", "--data", str(tmp_path / "y.npz"),
            "--n-test", "32"]
    assert main([*base, *BAD, "--out", str(tmp_path / "bad")]) == 3
    err = capsys.readouterr().err
    assert "error: the run failed: without x to score it, the unseen-energy test failed" in err
    m = json.loads((tmp_path / "bad" / "metrics.json").read_text())
    assert m["x_err"] is None and "unseen-energy" in m["failed"]
    assert main([*base, "--steps", "5", "--export-samples", "0", "--out", str(tmp_path / "good")]) == 0
    assert json.loads((tmp_path / "good" / "metrics.json").read_text())["failed"] is None


def test_python_train_records_the_verdict_and_warns_never_raises():
    """pdeinv.train returns the failed run with the reason in metrics['failed'] and a FailedRun warning;
    with y-only data the unseen-energy test judges; a good run: failed is None."""
    heat = pdeinv.load_problem("heat_1d", n=64, backend="modal")
    model = nets.whitened("linear")(heat)
    torch.manual_seed(0)
    with torch.no_grad():
        for w in model.parameters():
            w.normal_(0, 1.0)
    kw = {"steps": 2, "n_train": 64, "n_test": 16, "batch_size": 16, "progress": False}
    with pytest.warns(FailedRun, match="x_err"):
        r = pdeinv.train(heat, GD(optimizer=sgd(1e-3)), model, **kw)
    assert r.metrics["x_err"] > 1 and "x_err" in r.metrics["failed"]
    _, y = heat.sample(96, 1)
    with pytest.warns(FailedRun, match="unseen-energy"):
        r = pdeinv.train(heat, GD(optimizer=sgd(1e-3)), model, data=y,
                         **{k: v for k, v in kw.items() if k != "n_train"})  # the data's rows train
    assert r.metrics["x_err"] is None and "unseen-energy" in r.metrics["failed"]
    r = pdeinv.train(heat, pdeinv.SIP(), steps=3, n_train=64, n_test=16, batch_size=None, progress=False,
                     prior=None)
    assert r.metrics["failed"] is None
