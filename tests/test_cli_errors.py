"""How ``pdeinv`` reports each kind of failure: bad input exit 2, numerical failure or out of
memory exit 1, Ctrl-C exit 130 — each as one line on stderr without a traceback; a bug (any
other exception) keeps its traceback."""

import numpy as np
import pytest
from scipy.sparse.linalg import ArpackNoConvergence

from pdeinv.cli import main
from pdeinv.cli.commands import show
from pdeinv.errors import ConvergenceError, NonFiniteError, TooManyModes


@pytest.mark.parametrize("err, code, head", [
    (ValueError("kappa=-1.0 is not allowed; expected kappa > 0"), 2, "pdeinv show: error: kappa=-1.0"),
    (FileNotFoundError("mesh file 'm.msh' does not exist"), 2, "pdeinv show: error: mesh file"),
    (np.linalg.LinAlgError("Singular matrix"), 1, "pdeinv show: numerical failure: Singular matrix"),
    (NonFiniteError("step 3: the y-loss is inf"), 1, "pdeinv show: numerical failure: step 3"),
    (TooManyModes("would keep 900 of 961 modes; use backend=steps"), 1, "pdeinv show: numerical failure: "),
    (ConvergenceError("CG stopped at 1e-3"), 1, "pdeinv show: numerical failure: CG"),
    (ArpackNoConvergence("ARPACK error -1", np.zeros(0), np.zeros((2, 0))), 1,
     "pdeinv show: numerical failure: "),
    (MemoryError("Unable to allocate 80 GiB"), 1, "pdeinv show: out of memory: Unable to allocate 80 GiB"),
    (KeyboardInterrupt(), 130, "pdeinv show: interrupted"),
])
def test_each_failure_is_one_line_with_its_exit_code(monkeypatch, capsys, err, code, head):
    def fail(args):
        raise err

    monkeypatch.setattr(show, "cmd_show", fail)
    assert main(["show", "somewhere"]) == code
    out = capsys.readouterr().err.strip().splitlines()
    assert len(out) == 1 and out[0].startswith(head) and "Traceback" not in out[0]


def test_an_exception_in_code_outside_pdeinv_is_one_line_naming_it_and_v_shows_its_traceback(monkeypatch,
                                                                                           capsys):
    def fail(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(show, "cmd_show", fail)
    assert main(["show", "somewhere"]) == 2
    (err,) = capsys.readouterr().err.strip().splitlines()
    assert f"{__file__}, line" in err and "in fail: RuntimeError: a bug (-v shows the traceback)" in err
    assert main(["show", "somewhere", "-v"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("Traceback") and 'raise RuntimeError("a bug")' in err


def one_line(capsys, argv):
    """``pdeinv argv``: its exit code and its stderr, which must be one line without a traceback."""
    try:
        code = main(argv)
    except SystemExit as stop:  # argparse's own errors exit from parse_args
        code = stop.code
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and "usage:" not in err, err
    return code, err


@pytest.mark.parametrize("argv, needle", [
    (["train", "heat_1d", "--steps", "nan"], "argument --steps: invalid int value: 'nan'"),
    (["train", "heat_1d", "--method", "bogus"], "argument --method: invalid choice: 'bogus'"),
    (["demo", "heat_1d", "--batch", "1.5"], "argument --batch: invalid int value: '1.5'"),
    (["problems", "extra"], "unrecognized arguments: extra (`pdeinv problems --help`"),
    (["train", "heat_1d", "--bogus", "1"], "unrecognized arguments: --bogus 1 (`pdeinv train --help`"),
    (["trian", "heat_1d"], "invalid choice: 'trian'"),
    ([], "the following arguments are required: command"),
])
def test_argparse_errors_are_one_line(capsys, argv, needle):
    """argparse printed its whole usage block (12 lines for train) before its error; now the error alone."""
    code, err = one_line(capsys, argv)
    assert code == 2 and needle in err and "--help` lists the arguments" in err


@pytest.mark.parametrize("flag, value, allowed", [
    ("--steps", "-1", "an integer >= 1"), ("--lr", "0", "a number > 0"), ("--eta", "-2", "a number > 0"),
    ("--tau", "1", "a number >= 0 and < 1"), ("--batch-size", "0", "an integer >= 1"),
    ("--time-budget", "-1", "a number > 0"), ("--eval-every", "0", "an integer >= 1"),
    ("--max-failures", "0", "an integer >= 1"), ("--threads", "100000", "an integer from 1 to 1024"),
])
def test_train_flags_are_named_as_flags(capsys, tmp_path, flag, value, allowed):
    """``--steps -1`` said ``steps=-1`` (the trainer's name, easily read as ``--set steps=``, the physics'
    time steps); ``--threads 100000`` ended in a traceback (can't start new thread)."""
    code, err = one_line(capsys, ["train", "heat_1d", flag, value, "--out", str(tmp_path / "r")])
    assert code == 2 and f"{flag} {value} is not allowed; expected {allowed}" in err
    assert not (tmp_path / "r").exists()
