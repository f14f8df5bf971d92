"""What a run reports: its test-set errors, the check that its last update did not blow them up, and
its metrics.

Every ``eval_every`` steps (and after the first and the last) the trainer reports the mean relative
L²(Ω) errors on the held-out test set,

    x_err = mean_i ‖f(y*_i) − x_i‖_M / ‖x_i‖_M,   y_err = mean_i ‖P f(y*_i) − y*_i‖_M / ‖y*_i‖_M

(``y_err`` falls back to the Euclidean norm when observations are not fields on the mesh, e.g. sensor
time series; no ``x_err`` when the test set has no ``x``). A test row that is all zero (an empty box) is
measured against the test set's rms norm (:func:`pdeinv.fem.forms.relative_norms`).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import torch

from ..errors import NonFiniteError
from ..fem.forms import relative_norms
from ..methods.guard import ADVICE
from ..physics.capabilities import observes_field
from .stopping import observe
from .verdict import FailedRun, amplitude, failure, of_predictions


@torch.no_grad()
def evaluate(problem, model, test) -> dict:
    """Mean relative L²(Ω) x- and y-errors on ``test = (x or None, y numpy, y tensor)``."""
    x, y, y_t = test
    xhat, yhat = observe(problem.operator, model, y_t)
    if yhat is None:
        return {"y_err": math.nan} if x is None else {"x_err": math.nan, "y_err": math.nan}
    if observes_field(problem.operator):  # declared, never guessed from shapes
        y_err = problem.disc.relative_error(yhat, y)
    else:
        y_err = relative_norms(np.linalg.norm(yhat - y, axis=1), np.linalg.norm(y, axis=1))
    if x is None:
        return {"y_err": float(np.mean(y_err))}
    return {"x_err": float(np.mean(problem.relative_error(xhat, x))), "y_err": float(np.mean(y_err))}


def check_evaluation(y_err: float, start: float, max_loss_growth: float | None) -> None:
    """Reject the step just taken (:class:`NonFiniteError` with its ``overshoot``) when its test
    predictions are not finite, or their relative y-error exceeds ``√max_loss_growth`` times that of
    the network training started from (at least 1, a zero network's; the loss is its square): the
    loss-growth guard judges an update only at the next step, and the last step has none."""
    growth = math.inf if max_loss_growth is None else math.sqrt(max_loss_growth)
    bound = growth * max(start, 1.0)
    if not math.isfinite(y_err) or y_err > bound:
        err = NonFiniteError(f"the network's test y-error after this step is {y_err:.3g} (at the start "
                             f"{start:.3g}, the bound {bound:.3g}): its update blew up; it is undone "
                             f"({ADVICE})")
        err.overshoot = bound / y_err if math.isfinite(y_err) else None
        raise err


def metrics(trainer, run) -> dict:
    """``metrics.json`` of a finished run of ``trainer`` (:class:`pdeinv.Trainer`): where it stopped and
    why, its last errors and loss, its settings, what its data, stopping rule and target used, and its
    verdict ``failed`` (why it failed, or ``None``: :mod:`pdeinv.training.verdict`; warned as
    :class:`~pdeinv.training.verdict.FailedRun`)."""
    last, at = trainer.history[-1], run.at
    metrics = {
        "problem": trainer.problem.name, "method": trainer.rule.name,
        "steps": at.step, "wall_s": at.wall, "x_err": last.get("x_err"), "y_err": last["y_err"],
        "loss": last["loss"], "step_s": at.wall / at.step, "n_train": trainer.n_train,
        "n_test": trainer.n_test, "batch_size": trainer.batch_size, "seed": trainer.seed,
        "world_size": trainer.parallel.world_size, "device": str(trainer.device),
        "n_params": sum(p.numel() for p in run.model.parameters() if p.requires_grad),
        "rejected_steps": sum(1 for h in trainer.history if "rejected" in h),
        "stopped_by": at.stopped_by or ("steps" if trainer.steps is not None and at.step >= trainer.steps
                                        else "time_budget"),
    }
    if trainer._own is not None:
        metrics["data"] = trainer._own.describe()
    if run.stop_state is not None:
        metrics["stop_rule"] = {"name": trainer.stop.name, **trainer.stop.describe(run.stop_state)}
    if trainer._target_info is not None:
        metrics["target"] = trainer._target_info
    # the verdict (pdeinv.training.verdict); without x it rests on the unseen-energy test, which the trainer
    # also records under "unseen_energy" (computed twice then: cheap beside training)
    scored = last.get("x_err") is not None
    unseen = None if scored else of_predictions(trainer.problem, run.model, run.test, trainer.seed)[0]
    if not scored:
        metrics["amplitude"] = amplitude(trainer.problem, run.model, run.test, trainer.seed)
    metrics["failed"] = failure(metrics["x_err"], unseen, trainer.problem.N, metrics["y_err"],
                                metrics.get("amplitude"))
    if metrics["failed"] and trainer.parallel.is_writer:
        warnings.warn(f"the run failed: {metrics['failed']} (metrics['failed'])", FailedRun, stacklevel=3)
    return metrics


