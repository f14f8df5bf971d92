"""Whether a finished run failed: a result no better than not answering is never a success.

**With x** (the built-in scenes, or ``--data`` with ``x``): the zero prediction ``x̂ = 0`` has relative
error ``‖0 − x‖_M/‖x‖_M = 1`` on every sample, so a held-out

    x_err = mean_i ‖x̂_i − x_i‖_M / ‖x_i‖_M ≥ 1           (:data:`WORSE_THAN_ZERO`)

(or not finite) means the network does no better than predicting zero everywhere: a failure. The
SIP paper's heat experiment run with our defaults ended at 1.067 and exited 0 (issue 32).

**Without x** the run cannot be scored; what can be checked is the unseen-energy test
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


class FailedRun(RuntimeWarning):
    """A finished run failed its verdict (:func:`failure`); the reason is in ``metrics["failed"]``."""


def failure(x_err: float | None, unseen: dict | None, n_unknowns: int) -> str | None:
    """Why the run failed, or ``None``: ``x_err`` ≥ :data:`WORSE_THAN_ZERO` or not finite; without x
    (``x_err`` None), predictions above the unseen-energy bound (``unseen``: the record of
    :func:`pdeinv.training.unseen.unseen_energy`, with its ``bound``; ``None`` where the test does not
    apply)."""
    if x_err is not None:
        if math.isfinite(x_err) and x_err < WORSE_THAN_ZERO:
            return None
        return (f"the held-out x_err is {x_err:.4g}, at least {WORSE_THAN_ZERO:g}: no better than predicting "
                "zero everywhere")
    if unseen is None or unseen["prediction"] <= unseen["bound"]:
        return None
    ratio = unseen["prediction"] / max(unseen["prior"], 1e-300)
    return (f"without x to score it, the unseen-energy test failed: the predictions carry {ratio:.3g}× the "
            f"energy the scene's prior puts in the {n_unknowns - unseen['seen']} directions the physics "
            "cannot see (pdeinv.training.unseen; data from another prior can fail it too)")
