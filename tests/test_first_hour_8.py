"""Bad and odd inputs of the eighth round (issue 48): a user's module interruptible while its own code runs,
`pdeinv problems` past broken modules, a run's posterior bound to its run.json, one mismatch limit for
classical too, zero rows of y named, flags that do not apply refused (in --explain too), and the Python
API's arguments named. Each case failed (a traceback, a wrong exit 0, a hang or a misleading line) on the
code before."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.cli import main
from pdeinv.cli.signals import INTERRUPTED

ROOT = Path(__file__).resolve().parents[1]
DATA = ["--threads", "1", "-q", "--steps", "2", "--prior-fit", "0", "--n-test", "8", "--set", "n=8"]
SMALL = [*DATA, "--n-train", "16"]


def _one_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and "warning" not in err and err.count("\n") == 1, err
    return err


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two small heat_1d runs with posteriors (κ 0.01 and 0.02), and files of observations."""
    tmp = tmp_path_factory.mktemp("runs")
    assert main(["train", "heat_1d", *SMALL, "--out", str(tmp / "a")]) == 0
    assert main(["train", "heat_1d", *SMALL, "--set", "kappa=0.02", "--out", str(tmp / "b")]) == 0
    p = pdeinv.load_problem("heat_1d", n=8)
    x, y = p.sample(300, seed=3)
    np.savez(tmp / "clean.npz", x=x, y=y)
    y0 = y.copy()
    y0[10:20] = 0
    np.savez(tmp / "zero_rows.npz", x=x, y=y0)
    return tmp


def test_problems_lists_past_a_malformed_module(tmp_path, monkeypatch, capsys):
    (tmp_path / "bad_settings.py").write_text("SETTINGS = dict(n=8)\ndef make(**o):\n    pass\n")
    (tmp_path / "exits_import.py").write_text("import sys\nsys.exit(5)\n")
    monkeypatch.setenv("PDEINV_PROBLEMS", str(tmp_path))
    assert main(["problems"]) == 0
    out = capsys.readouterr().out
    assert "its SETTINGS is not a dict of (default, rule) pairs" in out
    assert "exits_import: cannot be imported (it calls sys.exit(5))" in out
    assert "wave_sensors_2d:" in out  # the listing went on


def test_a_module_that_loops_at_import_stops_on_ctrl_c(tmp_path):
    marker = tmp_path / "running"
    (tmp_path / "hang.py").write_text(f"import pathlib\npathlib.Path({str(marker)!r}).touch()\n"
                                      "while True:\n    pass\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "pdeinv", "train", str(tmp_path / "hang.py"), "--explain"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    deadline = time.monotonic() + 120
    while not marker.exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1].decode()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=30)  # it was held back for as long as the module ran
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError("Ctrl-C did not stop a module looping at import") from None
    assert proc.returncode == INTERRUPTED and "Traceback" not in err.decode(), err.decode()


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal of a device this machine lacks")
def test_explain_makes_the_runs_device_and_flag_checks(tmp_path, capsys):
    assert main(["train", "heat_1d", *SMALL, "--explain", "--device", "cuda"]) == 2
    assert "--device 'cuda': CUDA is not available here" in capsys.readouterr().err.splitlines()[-1]
    assert main(["train", "heat_1d", *SMALL, "--explain", "--resume", "--overwrite", "--out",
                 str(tmp_path / "r")]) == 2
    assert "--resume and --overwrite conflict" in _one_error(capsys)


def test_prior_fit_steps_on_a_network_without_a_prior_part_are_refused(tmp_path, capsys):
    args = ["train", "heat_1d", *[a for a in SMALL if a not in ("--prior-fit", "0")], "--prior-fit", "5",
            "--net", "linear"]
    assert main([*args, "--out", str(tmp_path / "r")]) == 2
    assert "--prior-fit 5 does not apply: --net linear of heat_1d has no part fitted on prior draws" in \
        _one_error(capsys)
    assert not (tmp_path / "r").exists()
    assert main([*args, "--explain"]) == 2


def test_predict_refuses_another_runs_or_a_missing_posterior(runs, tmp_path, capsys):
    run = tmp_path / "a"
    shutil.copytree(runs / "a", run)
    args = ["predict", str(run), "--data", str(runs / "clean.npz"), "--out", str(tmp_path / "p.npz"),
            "--threads", "1"]
    shutil.copy(runs / "b" / "posterior.npz", run / "posterior.npz")  # the same size, another run's
    assert main(args) == 2 and "posterior.npz is not the posterior its run.json was written with" in \
        _one_error(capsys)
    (run / "posterior.npz").unlink()
    assert main(args) == 2 and "its posterior.npz is missing (the run was calibrated" in _one_error(capsys)
    assert not (tmp_path / "p.npz").exists()
    shutil.copy(runs / "a" / "posterior.npz", run / "posterior.npz")
    assert main(args) == 0


def test_classical_judges_the_mismatch_at_the_declared_noise_as_train_does(runs, tmp_path, capsys):
    """κ = 0.02 against κ = 0.01 data: a noise level read off the y (0.14) had absorbed the mismatch."""
    data = str(runs / "clean.npz")
    assert main(["classical", "heat_1d", "--set", "n=8", "--set", "kappa=0.02", "--data", data,
                 "--threads", "1"]) == 3
    err = capsys.readouterr().err
    assert "far above the noise level 0 (noisy data: declare the level" in err
    assert main(["train", "heat_1d", *DATA, "--set", "kappa=0.02", "--data", data, "--out",
                 str(tmp_path / "r")]) == 3
    assert "above 0.05, the most noise of level 0 explains" in _one_error(capsys)


def test_zero_rows_of_y_whose_x_are_not_are_named(runs, tmp_path, capsys):
    data = str(runs / "zero_rows.npz")
    for args in (["train", "heat_1d", *DATA, "--out", str(tmp_path / "r")],
                 ["classical", "heat_1d", "--set", "n=8", "--threads", "1"],
                 ["predict", str(runs / "a"), "--out", str(tmp_path / "p.npz"), "--threads", "1"]):
        assert main([*args, "--data", data]) == 3, args
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert "rows 10–19 of y are all zero while their x are not" in err, err


def test_a_changed_data_file_on_resume_is_named_as_such(runs, tmp_path, capsys):
    out = str(tmp_path / "r")
    args = ["train", "heat_1d", *DATA, "--checkpoint-every", "1", "--out", out]
    assert main(args) == 0
    assert main([*args, "--resume", "--data", str(runs / "clean.npz")]) == 2
    err = _one_error(capsys)
    assert "data=none (the scene's draws) (checkpoint) vs a file of fingerprint" in err and "(--data)" in err
    assert "Refined" not in err and "n_train" not in err


def test_a_physics_that_observes_nothing_or_a_zero_prior_says_so_in_one_line(tmp_path, capsys):
    assert main(["train", "heat_1d", *SMALL, "--set", "kappa=1e3", "--out", str(tmp_path / "k")]) == 2
    assert "the physics leaves nothing to observe" in _one_error(capsys)  # no numpy 0/0 warning before it
    module = tmp_path / "zeros.py"
    module.write_text("import numpy as np\nimport pdeinv\n"
                      "def make(**o):\n    p = pdeinv.load_problem('heat_1d', n=8)\n"
                      "    return pdeinv.Problem('zeros', p.disc, p.operator,\n"
                      "                          lambda n, rng: np.zeros((n, p.N)),\n"
                      "                          inverse_simulator=p.inverse_simulator)\n")
    assert main(["train", str(module), *DATA[:-2], "--n-train", "16", "--out", str(tmp_path / "z")]) == 2
    assert "prior draws are all zero fields" in _one_error(capsys)


def test_a_run_with_nothing_left_to_plot_on_a_log_axis_draws_it_without_a_warning(tmp_path, capsys):
    code = main(["train", "heat_1d", *SMALL, "--set", "noise=1e10", "--out", str(tmp_path / "r")])
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line.lower()]
    # the run fails; its picture is drawn, with no plotting warning: the one warning names the blind physics
    assert code == 3 and len(warnings) == 1 and "the physics resolves 0 of the 7 directions" in warnings[0]
    assert (tmp_path / "r" / "training.png").is_file()


def test_save_run_keeps_a_problems_own_settings(tmp_path):
    p = pdeinv.load_problem("heat_1d", n=8)
    res = pdeinv.train(p, "sip", steps=2, n_train=16, n_test=8, prior=None)
    pdeinv.save_run(tmp_path / "r", p, model=res.model, posterior=res.posterior)
    assert json.loads((tmp_path / "r" / "run.json").read_text())["overrides"] == {"n": "8"}
    problem, _ = pdeinv.io.runs.load_run(tmp_path / "r")
    assert problem.N == p.N == 7


def test_the_api_names_its_arguments():
    p = pdeinv.load_problem("heat_1d", n=8)
    x, _ = p.sample(2)
    with pytest.raises(TypeError, match=r"^problem='heat_1d' is str, not a pdeinv.Problem; load it with"):
        pdeinv.nets.default_model("heat_1d")
    with pytest.raises(TypeError, match=r"^problem='heat_1d' is str"):
        pdeinv.io.export.write_fields("f.vtu", "heat_1d", x, x)
    with pytest.raises(TypeError, match=r"^bars=5 is not allowed; expected a dict with 'std', 'lo' and 'hi'"):
        pdeinv.io.export.write_fields("f.vtu", p, x, x, bars=5)
    with pytest.raises(ValueError, match=r"^hidden=\(-1,\) is not allowed; expected integer widths >= 1"):
        pdeinv.nets.mlp(hidden=(-1,))
    with pytest.raises(ValueError, match=r"^hidden=\(0,\) is not allowed"):
        pdeinv.nets.mlp(hidden=(0,))
    with pytest.raises(TypeError, match=r"^hidden='64' is str; expected a tuple of integer widths"):
        pdeinv.nets.mlp(hidden="64")
    with pytest.raises(TypeError, match=r"^activation=5 is not allowed; expected a torch.nn.Module class"):
        pdeinv.nets.mlp(activation=5)
    with pytest.raises(ValueError, match=r"^PriorFit\(seed\)=-1 is not allowed"):
        pdeinv.nets.refine.PriorFit(seed=-1)
    _, y = p.sample(64)
    with pytest.raises(ValueError, match=r"^data is a tensor on the 'meta' device"):
        pdeinv.Trainer(p, "sip", data=torch.tensor(y, device="meta"), steps=2, n_test=8, prior=None).fit()
    with pytest.raises(ValueError, match=r"^model has tensors on the 'meta' device"):
        pdeinv.train(p, "sip", model=torch.nn.Linear(7, 7).to("meta"), steps=2, n_train=16, n_test=8,
                     prior=None)


def test_numpy_numbers_are_settings_too():
    n8 = pdeinv.load_problem("heat_1d", n=8).N
    assert pdeinv.load_problem("heat_1d", n=np.float32(8)).N == n8
    assert pdeinv.load_problem("heat_1d", n=np.int32(8)).N == n8
    with pytest.raises(ValueError, match=r"^n=8.5 is not allowed; expected an integer"):
        pdeinv.load_problem("heat_1d", n=np.float32(8.5))


def test_round_8b_device_stage_name_posterior_folder_and_a_module_without_make(tmp_path, monkeypatch, capsys):
    from pdeinv.physics.backends.device import resolve
    from pdeinv.training.plan import PriorStage

    with pytest.raises(ValueError, match=r"^device 'cpu:1' is not supported"):
        resolve("cpu:1")
    with pytest.raises(TypeError, match=r"^PriorStage\(name\)=5 is int"):
        PriorStage(name=5)
    with pytest.raises(ValueError, match=r"is not a directory"):
        pdeinv.io.runs.load_posterior(tmp_path / "nope")
    (tmp_path / "no_make.py").write_text("x = 1\n")
    monkeypatch.setenv("PDEINV_PROBLEMS", str(tmp_path))
    assert main(["problems"]) == 0
    assert "no_make: has no function make(**overrides)" in capsys.readouterr().out


def test_predict_warns_on_a_run_that_failed_its_own_check(runs, tmp_path, capsys):
    run = tmp_path / "a"
    shutil.copytree(runs / "a", run)
    metrics = json.loads((run / "metrics.json").read_text())
    (run / "metrics.json").write_text(json.dumps({**metrics, "failed": "the held-out x_err is 1"}))
    assert main(["predict", str(run), "--data", str(runs / "clean.npz"), "--out", str(tmp_path / "p.npz"),
                 "--threads", "1"]) == 0
    assert "failed its own check (the held-out x_err is 1)" in capsys.readouterr().err
