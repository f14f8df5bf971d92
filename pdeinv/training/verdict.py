"""Whether a finished run failed: a result no better than not answering is never a success.

**With x** (the built-in scenes, or ``--data`` with ``x``): the zero prediction ``x̂ = 0`` has relative
error ``‖0 − x‖_M/‖x‖_M = 1`` on every sample, so a held-out

    x_err = mean_i ‖x̂_i − x_i‖_M / ‖x_i‖_M ≥ 1           (:data:`WORSE_THAN_ZERO`)

(or not finite) means the network does no better than predicting zero everywhere: a failure (a run
of the SIP paper's heat experiment once ended at 1.067 and still exited 0).

**With or without x**, the held-out ``y_err = mean_i ‖P x̂_i − y_i‖/‖y_i‖ ≥ 1`` means the physics of the
predictions explains the observations no better than ``x̂ = 0`` (whose ``y_err`` is 1): the data do not
come from this problem's physics and settings (another κ, T, mesh, scene), or the run diverged (a
heat_2d run fed wave_2d data reaches 1.45; every built-in scene stays far below 1).

**Without x**, predictions whose rms amplitude is more than :data:`AMPLITUDE` (100) times the prior's,
per unit of the observations' amplitude (so that data in any units get the same verdict), cannot be this
problem's fields: data from another physics can be fitted by fields far larger than the
prior's (wave_1d data fed to heat_1d: ~1e8 times), while data from another prior stay within a few times.

Beyond that the run cannot be scored; what can be checked is the unseen-energy test
(:mod:`pdeinv.training.verdict`): predictions carrying more than ``FACTOR`` times the prior's energy where the
physics cannot see hold what neither the data nor the prior support, which only adds to the error.
Operators that see every direction (the wave scenes) have no such test, and no verdict without x.
The prior it compares with is the scene's (nothing in ``y`` shows the unseen directions), so data
from another prior can fail it on a good run (y-only heat files drawn from another prior often do); the
message says so, and ``--accept-bad`` keeps such a run.

``pdeinv.train`` records the reason in ``metrics["failed"]`` (``None`` for a success) and warns with
:class:`FailedRun`; ``pdeinv train`` writes every file, then ends with exit code 3 and one line,
unless ``--accept-bad``.

**The unseen energy** (:func:`unseen_energy`, also a warning of every finished run): the energy a
trained network puts where the physics cannot see, against the prior's own.

With the operator's spectral basis ``P = Out diag(g) Inᵀ`` (:class:`pdeinv.physics.capabilities.Spectral`)
the directions of ``x`` the observations resolve are those of gain above the noise level ``δ``
(noise-free: :data:`FLOOR` of the largest), spanned by ``Q = orth(In[:, g > max(δ, FLOOR)·g_max])``;
everything else is *unseen*. With ``U = I − QQᵀ`` (Euclidean coefficients),

    e(X) = mean_i ‖U x_i‖²

No estimator learns ``U x`` from ``y`` beyond what the prior ties to the seen part, and the best one,
the conditional mean, shrinks it: ``E‖E[Ux | y]‖² ≤ E‖Ux‖²``. A network whose predictions carry more
than :data:`FACTOR` times the prior's unseen energy (plus :data:`SLACK` of the prior's total) there
puts in what neither the data nor the prior support — weights the training never moved from a
random start, or Adam's per-parameter scaling, whose steps leave the span of ``Pᵀ`` (Adam on heat_1d:
13× the prior's) — and :func:`unseen_energy` says so. Nothing is computed for an operator without a
spectral basis (a time-stepping or reversible one: the wave scenes see every direction).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..physics.capabilities import modal_basis

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
    unseen-energy bound (``unseen``: the record of :func:`pdeinv.training.verdict.unseen_energy`, with its
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
                "physics cannot see (pdeinv.training.verdict; data from another prior can fail it too)")
    if amplitude is not None and not (math.isfinite(amplitude) and amplitude < AMPLITUDE):
        return (f"without x to score it, the predictions are {amplitude:.3g}× the prior's rms amplitude, per "
                f"unit of the observations' (a run passes below {AMPLITUDE:g}×): no field of this problem's "
                "prior explains these observations "
                "(data from another physics or settings such as κ, T or the mesh, or undeclared noise?)")
    return y_why


#: gains below this fraction of the largest count as unseen on noise-free data (rounding)
FLOOR = 1e-12
#: the predictions' unseen energy a warning tolerates, in units of the prior's (module docstring)
FACTOR = 2.0
#: and in units of the prior's total energy
SLACK = 0.01
#: a prior with more than this fraction of its energy unseen: the data decide less than half of x, said
#: (every built-in scene's default stays below 0.15)
BLIND = 0.5


def unseen_energy(problem, xhat: np.ndarray, xref: np.ndarray) -> tuple[dict | None, str | None]:
    """``({"prediction": e(x̂), "prior": e(x_ref), "seen": k, "bound": the tolerated e}, warning or None)``
    (module docstring);
    ``(None, None)`` when the operator has no spectral basis or sees every direction."""
    basis = modal_basis(problem.operator)
    if basis is None:
        return None, None
    g = np.asarray(basis.g, dtype=float)
    keep = g > max(float(problem.noise or 0.0), FLOOR) * g.max()
    if keep.sum() >= problem.N:
        return None, None
    Q = np.linalg.qr(np.asarray(basis.In, dtype=float)[:, keep])[0]

    def energy(X):
        X = np.asarray(X, dtype=float)
        return float(np.mean(np.sum((X - (X @ Q) @ Q.T) ** 2, axis=1)))

    pred, prior = energy(xhat), energy(xref)
    total = float(np.mean(np.sum(np.asarray(xref, dtype=float) ** 2, axis=1)))
    bound = FACTOR * prior + SLACK * total
    record = {"prediction": pred, "prior": prior, "seen": int(keep.sum()), "bound": bound}
    if pred <= bound:
        return record, (None if prior <= BLIND * total else (
            f"the physics resolves {record['seen']} of the {problem.N} directions of x (gain above "
            f"{max(problem.noise, FLOOR):g} of the largest), and {prior / total:.0%} of the prior's energy "
            "lies outside them: the estimate is mostly the prior's, whatever the training (settings such as "
            "κ, T, the sensors or the noise leave little to recover)"))
    ratio, unseen = pred / max(prior, np.finfo(float).tiny), problem.N - int(keep.sum())
    return record, (f"the predictions carry {ratio:.3g}× the prior's energy in the {unseen} directions the "
                    f"physics cannot see (gain below {max(problem.noise, FLOOR):g} of the largest): the data "
                    "cannot have put it there and the prior holds less, so it adds to x_err (Adam's "
                    "per-parameter scaling, for one, moves those directions)")


@torch.no_grad()
def amplitude(problem, model, test: tuple, seed: int) -> float:
    """``(rms x̂ / rms x_ref) / (rms y / rms y_ref)``: the predictions' rms amplitude in units of the
    prior's, per unit of the observations' (the reference ``x_ref`` as in :func:`of_predictions`, ``y_ref``
    its noise-free observations). Observations ``c`` times the prior's (a file in other units) give
    predictions ``c`` times the prior's, and the same figure: the test asks whether the physics explains
    the observations with fields of the prior's size, not in which units they are. Observations all zero:
    the predictions' amplitude alone."""
    from .trainset import TEST_DATA, seed_stream

    x, y, y_t = test
    if x is None:
        x = problem.sample(len(y_t), seed_stream(seed, TEST_DATA))[0]
    x = np.asarray(x, dtype=float)
    xhat = model(y_t).double().cpu().numpy()

    def rms(a):  # root-mean-square norm of the rows, scaled first: no overflow for data at 1e±300
        a = np.asarray(a, dtype=float)
        top = float(np.max(np.abs(a))) if a.size else 0.0
        return top * math.sqrt(float(np.mean(np.sum((a / top) ** 2, axis=1)))) if top > 0 else 0.0

    tiny = np.finfo(float).tiny
    ratio = rms(xhat) / max(rms(x), tiny)
    y_obs, y_ref = rms(y), rms(problem.operator.forward(x))
    return ratio / (y_obs / y_ref) if y_obs > 0 and y_ref > 0 else ratio


@torch.no_grad()
def of_predictions(problem, model, test: tuple, seed: int) -> tuple[dict | None, str | None]:
    """:func:`unseen_energy` of ``model``'s predictions on a trainer's ``test = (x or None, y, y
    tensor)``; without ``x`` the reference is as many prior samples (the test stream of ``seed``)."""
    from .trainset import TEST_DATA, seed_stream

    x, _, y_t = test
    if x is None:
        x = problem.sample(len(y_t), seed_stream(seed, TEST_DATA))[0]
    return unseen_energy(problem, model(y_t).double().cpu().numpy(), x)
