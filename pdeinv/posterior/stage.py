"""The calibration stage: the last stage of a run, which gives its network a calibrated posterior.

After the rule's stage (and the prior stage), the trained network ``f`` is applied to ``rows`` held-out
pairs ``(x, y)`` that no stage saw: draws of the scene's prior from their own seed stream (the trainer's
``draw``: :data:`pdeinv.training.trainset.CALIBRATION_DATA`). Their residuals ``x − f(y)`` fit a
:class:`pdeinv.posterior.conformal.Calibration` (the first half: the per-node scale and the residuals
kept for samples; the second half: the split-conformal quantiles), and its coverage, credible-ball
coverage, SBC p-values and interval width are measured on the run's test rows
(:func:`pdeinv.posterior.diagnostics.report`), which took no part in it. The stage reports them in
``metrics["stages"]`` and ``metrics["posterior"]``.

Own data *with* ``x``: the stage takes its rows from the file (:meth:`CalibrationStage.own_rows`, split off
before the rules and the prior stage see any: :func:`pdeinv.training.data.own_data`), never the test
rows. Without a prior to draw from (own data without ``x``) there is nothing to calibrate against: the
stage says so and the run has no posterior.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from .conformal import Calibration
from .diagnostics import report
from .predictive import forward as predict

#: held-out prior draws of the default stage: half fix the spread, half the conformal quantiles (2048
#: rows give the 90 % ball's radius to ±0.7 % coverage and each node's scale to ±1.6 %); fewer on large
#: meshes, so that the residuals held at once stay within ROW_NUMBERS numbers (160 MB), at least MIN_ROWS
ROWS, ROW_NUMBERS, MIN_ROWS = 4096, 20_000_000, 512


def row_count(N: int) -> int:
    """The default stage's held-out draws for ``N`` unknowns (:data:`ROWS`)."""
    return int(min(ROWS, max(MIN_ROWS, ROW_NUMBERS // N)))


#: own data with ``x``: at most this share of the rows left after the test and stopping rows is held out
#: for the calibration (the rest trains), and at least OWN_MIN rows, else none (too few for its two halves)
OWN_SHARE, OWN_MIN = 0.2, 64

#: stored residuals for samples: at most this many numbers (float16: 17 MB), 256 to 2048 rows. Every
#: sample of every observation is one of them, so their count bounds how well samples are calibrated
#: (SBC against ``k`` references errs by about ``0.8/√k``): heat_boxes 64² at 1 % kept 1 007 under 4·10⁶
#: numbers, and its 2 000-row field-mean SBC p rose from 0.26 / 3e-7 / 0.11 to 0.70 / 1e-4 / 0.28 with 2 048
#: (three calibration seeds, benchmarks/notes/posterior.md)
KEEP_NUMBERS, KEEP_ROWS = 2**23, (256, 2048)


@dataclass(frozen=True)
class CalibrationStage:
    """Calibrate the trained network on ``rows`` held-out prior draws (``None``: :func:`row_count`; module
    docstring); ``keep`` of the spread rows' residuals are stored for samples (``None``:
    :data:`KEEP_NUMBERS` numbers)."""

    rows: int | None = None
    keep: int | None = None
    name: str = "calibration"

    def __post_init__(self):
        from .._checks import label

        label(self.name, "CalibrationStage(name)")
        for key, value, low in (("rows", self.rows, 4), ("keep", self.keep, 1)):
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"CalibrationStage({key}={value!r}) is not allowed; expected an integer "
                                 f">= {low}")

    def own_rows(self, rows: int) -> int:
        """The rows a data file with ``x`` gives the stage, of the ``rows`` left after its test and stopping
        rows: ``rows`` of the stage if set, else :data:`OWN_SHARE` of them; 0 below :data:`OWN_MIN`."""
        n = self.rows if self.rows is not None else int(OWN_SHARE * rows)
        return n if n >= OWN_MIN else 0

    def why_not(self, problem, own) -> str | None:
        if own is None:
            return None
        if own.x_test is None:
            return "no prior: the data file has no x, so no error can be measured"
        if own.x_cal is None:
            return f"the data file has too few rows to hold out the calibration's {OWN_MIN}"
        return None

    def planned(self, problem, own=None) -> dict:
        why = self.why_not(problem, own)
        if why is not None:
            return {"name": self.name, "skipped": why}
        if own is not None:
            return {"name": self.name, "rows": len(own.x_cal), "own": True}
        return {"name": self.name, "rows": self.rows or row_count(problem.N),
                "prior": problem.settings.get("prior", "the scene's")}

    def run(self, problem, model, own, seed: int, test, draw) -> tuple[Calibration | None, dict]:
        """``(calibration or None, what the stage reports)``; ``test = (x, y, ...)`` the run's test rows,
        ``draw(n) -> (x, y)`` the held-out prior draws (their own seed stream)."""
        t0 = time.perf_counter()
        why = self.why_not(problem, own)
        if why is not None:
            return None, {"name": self.name, "skipped": why, "seconds": time.perf_counter() - t0}
        if own is not None:
            x, y = own.x_cal, own.y_cal
        else:
            x, y = draw(self.rows or row_count(problem.N))
        rows = len(x)
        mean = predict(model, y)
        residual = x - mean
        half = rows // 2
        mass = problem.disc.M if problem.disc is not None else None
        lo, hi = KEEP_ROWS
        keep = self.keep or int(np.clip(KEEP_NUMBERS // problem.N, lo, hi))
        cal = Calibration.fit(residual[:half], residual[half:], mass, keep)
        cal = replace(cal, probe_y=np.array(y[0], dtype=float), probe_x=mean[0])  # its network
        info = {"name": self.name, "rows": rows, "spread_rows": half, "conformal_rows": rows - half,
                "source": "prior" if own is None else "data"}
        x_test, y_test = test[0], test[1]
        if x_test is not None:
            info["test"] = report(cal, predict(model, y_test), x_test, mass, seed)
        return cal, {**info, "seconds": time.perf_counter() - t0}


def stage(value):
    """``calibration=``: ``"auto"`` (the default :class:`CalibrationStage`), ``None`` (none) or a stage."""
    if isinstance(value, str) and value == "auto":
        return CalibrationStage()
    if value is not None and not isinstance(value, CalibrationStage):
        raise TypeError(f"calibration={value!r} is not allowed; expected 'auto', None or a "
                        "pdeinv.posterior.CalibrationStage")
    return value
