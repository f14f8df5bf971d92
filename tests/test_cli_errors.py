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


def test_a_bug_keeps_its_traceback(monkeypatch):
    def fail(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(show, "cmd_show", fail)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["show", "somewhere"])
