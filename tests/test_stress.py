"""Stress sweeps: every outcome is classified; the HIG τ = 0 explosion is reproduced and τ > 0 is not."""

import json
import math

import numpy as np
import pytest
from scipy.sparse.linalg import ArpackNoConvergence

from pdeinv.bench.stress import OUTCOMES, Case, classify, counts
from pdeinv.cli import main
from pdeinv.errors import ConvergenceError, TooManyModes
from pdeinv.methods import NonFiniteError


def _raise(err):
    def run():
        raise err

    return run


@pytest.mark.parametrize("run, outcome", [
    (lambda: {"x_err": math.nan}, "nan"),  # an injected NaN
    (lambda: {"growth": math.inf}, "nan"),
    (_raise(NonFiniteError("step 3: the y-loss is inf")), "nan"),
    (lambda: {"x_err": 1e6}, "diverged"),
    (lambda: {"forward_err": 1e6, "growth": 0.5}, "ok"),  # accuracy is reported, not watched
    (_raise(ValueError("scheme='fe' is not allowed")), "refused"),
    (_raise(RuntimeError("boom")), "error"),
    # numerical failures on valid input are neither bad input nor bugs
    (_raise(np.linalg.LinAlgError("Singular matrix")), "failed"),  # a ValueError in numpy
    (_raise(TooManyModes("the modal backend would keep 900 of 961 modes")), "failed"),
    (_raise(ConvergenceError("CG: residual 1e-3 after 1000 iterations")), "failed"),
    (_raise(ArpackNoConvergence("ARPACK did not converge", np.zeros(0), np.zeros((3, 0)))), "failed"),
    (_raise(MemoryError("cannot allocate 80 GiB")), "error"),
    (lambda: {"x_err": 0.1, "backend": "modal"}, "ok"),
])
def test_classify(run, outcome):
    row = classify(Case("s", 1, run))
    assert row["outcome"] == outcome
    if outcome != "ok":
        assert row["message"]
    if outcome in ("failed", "error"):  # the type says which failure it was
        assert row["message"].startswith(type(_catch(run)).__name__ + ": ")


def _catch(run):
    try:
        run()
    except Exception as err:  # noqa: BLE001
        return err


def test_an_interrupt_is_not_a_case_outcome():
    with pytest.raises(KeyboardInterrupt):
        classify(Case("s", 1, _raise(KeyboardInterrupt())))


def test_stress_cli_quick(tmp_path):
    assert main(["stress", "heat_2d", "--quick", "--set", "n=8", "--set", "steps=10",
                 "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "stress.json").read_text())
    rows = res["cases"]
    assert all(r["outcome"] in OUTCOMES for r in rows)
    assert counts(rows)["error"] == 0 and sum(res["counts"].values()) == len(rows)
    by = {(r["sweep"], r["value"]): r for r in rows}
    assert by[("explicit", "fe")]["outcome"] == "refused" and "'be'" in by[("explicit", "fe")]["message"]
    assert by[("hig_tau", 0.0)]["outcome"] in ("nan", "diverged")  # full inversion explodes
    assert by[("hig_tau", 0.01)]["outcome"] == "ok"
    for tau in (0.0, 0.01):  # --method hig as shipped (Kronecker route): stable at every τ of the sweep
        assert by[("hig_tau_default", tau)]["outcome"] == "ok" and by[("hig_tau_default", tau)]["x_err"] < 0.9
    for r in rows:
        if r["sweep"].startswith("dt_"):
            assert r["outcome"] == "ok" and r["growth"] <= 1.0  # BE and CN never amplify


def test_stress_bad_input(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["stress", "heat_2d", "--out", str(f)]) == 2
    assert main(["stress", "nope", "--out", str(tmp_path / "o")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 2
