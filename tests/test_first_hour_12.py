"""Bad and odd inputs of the twelfth round (issue 48): a setting given twice, an output path through a
dangling link or with a name longer than the file system takes, a relative cut of 1 or more, a mismatched
file under `--explain`, `classical` on y no closer to P x than to 0, an async `make`, a device as a
problem module. Each case was a wrong exit 0, a second exit code for one refusal, a numpy warning or an
internal name on the code before."""

from __future__ import annotations

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main

SMALL = ["--set", "n=8", "--steps", "2", "--n-train", "32", "--n-test", "8", "--prior-fit", "0",
         "--threads", "1", "-q"]


def _one_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and "Warning" not in err and err.count("\n") == 1, err
    return err


def test_a_setting_given_twice_is_refused(tmp_path, capsys):
    assert main(["train", "heat_1d", *SMALL, "--set", "n=16", "--out", str(tmp_path / "r")]) == 2
    assert "--set n= is given twice, as '8' and '16'" in _one_error(capsys)
    assert not (tmp_path / "r").exists()


def test_an_output_through_a_dangling_link_is_refused(tmp_path, capsys):
    (tmp_path / "link").symlink_to(tmp_path / "missing" / "deeper")
    assert main(["train", "heat_1d", *SMALL, "--out", str(tmp_path / "link")]) == 2
    assert "a symbolic link to" in _one_error(capsys)
    assert not (tmp_path / "missing").exists()


def test_a_name_longer_than_the_file_system_takes_is_a_usage_error(tmp_path, capsys):
    assert main(["train", "heat_1d", *SMALL, "--out", str(tmp_path / ("a" * 300))]) == 2
    assert "300 bytes long; expected at most 255" in _one_error(capsys)


@pytest.mark.parametrize("tol", ["1", "2"])
def test_a_relative_cut_of_one_or_more_is_refused(tol):
    with pytest.raises(ValueError, match=f"tol={float(tol)!r} is not allowed; expected a relative cut 0 <"):
        pdeinv.load_problem("heat_1d", n=8, tol=tol)


def test_explain_refuses_mismatched_data_as_the_run_does(tmp_path, capsys):
    p = pdeinv.load_problem("heat_1d", n=16)
    x, y = p.sample(200, 0)
    np.savez(tmp_path / "other.npz", x=x, y=1.5 * y + 0.5 * np.roll(y, 3, axis=1))
    args = ["train", "heat_1d", "--set", "n=16", "--data", str(tmp_path / "other.npz")]
    assert main([*args, "--explain"]) == 3
    explained = _one_error(capsys)
    assert main([*args, "--steps", "2", "--prior-fit", "0", "--out", str(tmp_path / "r")]) == 3
    assert _one_error(capsys) == explained and "--accept-bad" in explained and "accept_bad=" not in explained


def test_classical_on_y_no_closer_to_p_x_than_to_zero_is_one_line_and_exit_3(tmp_path, capsys):
    p = pdeinv.load_problem("heat_1d", n=16)
    x, y = p.sample(200, 0)
    np.savez(tmp_path / "units.npz", x=x, y=y * 1e200)  # y in other units than x: P x is 0 beside y
    assert main(["classical", "heat_1d", "--set", "n=16", "--data", str(tmp_path / "units.npz")]) == 3
    err = _one_error(capsys)
    assert "differ from this problem's P x by 1" in err and "nothing solved" in err


def test_an_async_make_is_named_without_a_runtime_warning(tmp_path, capsys):
    module = tmp_path / "asyncmake.py"
    module.write_text("async def make(**kw):\n    return 2\n")
    assert main(["train", str(module), *SMALL, "--out", str(tmp_path / "r")]) == 2
    err = _one_error(capsys)
    assert "make() returned coroutine" in err and "not async" in err


def test_a_device_is_not_a_problem_module(capsys):
    assert main(["train", "/dev/null", "--explain"]) == 2
    assert "is not a regular file" in _one_error(capsys)
