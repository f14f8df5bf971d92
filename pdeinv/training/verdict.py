"""Whether a finished run failed: a result no better than not answering is never a success.

**With x** (the built-in scenes, or ``--data`` with ``x``): the zero prediction ``x̂ = 0`` has relative
error ``‖0 − x‖_M/‖x‖_M = 1`` on every sample, so a held-out

    x_err = mean_i ‖x̂_i − x_i‖_M / ‖x_i‖_M ≥ 1           (:data:`WORSE_THAN_ZERO`)

(or not finite) means the network does no better than predicting zero everywhere: a failure. The
SIP paper's heat experiment run with our defaults ended at 1.067 and exited 0 (issue 32).

**With or without x**, the held-out ``y_err = mean_i ‖P x̂_i − y_i‖/‖y_i‖ ≥ 1`` means the physics of the
predictions explains the observations no better than ``x̂ = 0`` (whose ``y_err`` is 1): the data do not
come from this problem's physics and settings (another κ, T, mesh, scene), or the run diverged. Measured
on a heat_2d run fed wave_2d data: y_err 1.45 (issue 36), against 1e-3–0.1 on every built-in scene.

**Without x**, predictions whose rms amplitude is more than :data:`AMPLITUDE` (100) times the prior's
cannot be this problem's fields: wave_1d data fed to heat_1d (SIP, CLI defaults) fit the observations
(y_err 0.006) with fields 1.6e8 times the prior's size, while data from another prior stay far below
(y-only heat_2d files (n = 16) of the box and random-field priors, 0 and 1 % noise, SIP: 1.0–4.1×).

Beyond that the run cannot be scored; what can be checked is the unseen-energy test
(:mod:`pdeinv.training.unseen`): predictions carrying more than ``FACTOR`` times the prior's energy where the
physics cannot see hold what neither the data nor the prior support, which only adds to the error.
Operators that see every direction (the wave scenes) have no such test, and no verdict without x.
The prior it compares with is the scene's (nothing in ``y`` shows the unseen directions), so data
from another prior can fail it on a good run: y-only files of heat_1d/heat_2d drawn from the box
or random-field prior, default SIP, failed it in 5 of 8 cases at x-errors 0.03–0.47 (no run had
x_err ≥ 1); the message says so, and ``--accept-bad`` keeps such a run.

``pdeinv.train`` records the reason in ``metrics["failed"]`` (``None`` for a success) and warns with
:class:`FailedRun`; ``pdeinv train`` writes every file, then ends with exit code 3 and one line,
unless ``--accept-bad``.
"""

from __future__ import annotations

import math

#: a held-out x_err at or above this is no better than the zero prediction (module docstring)
WORSE_THAN_ZERO = 1.0
#: without x, predictions of more than this many times the prior's rms amplitude fail (module docstring)
AMPLITUDE = 100.0


class FailedRun(RuntimeWarning):
    """A finished run failed its verdict (:func:`failure`); the reason is in ``metrics["failed"]``."""


def failure(x_err: float | None, unseen: dict | None, n_unknowns: int,
            y_err: float | None = None, amplitude: float | None = None) -> str | None:
    """Why the run failed, or ``None``, the most specific reason first: with x, ``x_err`` ≥
    :data:`WORSE_THAN_ZERO` or not finite; without x (``x_err`` None), predictions above the
    unseen-energy bound (``unseen``: the record of :func:`pdeinv.training.unseen.unseen_energy`, with its
    ``bound``; ``None`` where the test does not apply), then an rms ``amplitude`` of at least
    :data:`AMPLITUDE` times the prior's; in both cases ``y_err`` ≥ :data:`WORSE_THAN_ZERO` or not
    finite."""
    y_failed = y_err is not None and not (math.isfinite(y_err) and y_err < WORSE_THAN_ZERO)
    y_why = (f"the held-out y_err is {y_err:.4g}, at least {WORSE_THAN_ZERO:g}: the physics of the "
             "predictions explains the observations no better than predicting zero (a diverged run, or data "
             "from another physics or settings such as κ, T or the mesh?)") if y_failed else None
    if x_err is not None:
        if not (math.isfinite(x_err) and x_err < WORSE_THAN_ZERO):
            return (f"the held-out x_err is {x_err:.4g}, at least {WORSE_THAN_ZERO:g}: no better than "
                    "predicting zero everywhere")
        return y_why
    if unseen is not None and unseen["prediction"] > unseen["bound"]:
        ratio = unseen["prediction"] / max(unseen["prior"], 1e-300)
        return (f"without x to score it, the unseen-energy test failed: the predictions carry {ratio:.3g}× "
                f"the energy the scene's prior puts in the {n_unknowns - unseen['seen']} directions the "
                "physics cannot see (pdeinv.training.unseen; data from another prior can fail it too)")
    if amplitude is not None and not (math.isfinite(amplitude) and amplitude < AMPLITUDE):
        return (f"without x to score it, the predictions are {amplitude:.3g}× the prior's rms amplitude (at "
                f"most {AMPLITUDE:g} passes): no field of this problem's prior explains these observations "
                "(data from another physics or settings such as κ, T or the mesh, or undeclared noise?)")
    return y_why
