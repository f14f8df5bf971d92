"""Energy a trained network puts where the physics cannot see, against the prior's own.

With the operator's spectral basis ``P = Out diag(g) Inᵀ`` (:class:`pdeinv.physics.capabilities.Spectral`)
the directions of ``x`` the observations resolve are those of gain above the noise level ``δ``
(noise-free: :data:`FLOOR` of the largest), spanned by ``Q = orth(In[:, g > max(δ, FLOOR)·g_max])``;
everything else is *unseen*. With ``U = I − QQᵀ`` (Euclidean coefficients),

    e(X) = mean_i ‖U x_i‖²

No estimator learns ``U x`` from ``y`` beyond what the prior ties to the seen part, and the best one,
the conditional mean, shrinks it: ``E‖E[Ux | y]‖² ≤ E‖Ux‖²``. A network whose predictions carry more
than :data:`FACTOR` times the prior's unseen energy (plus :data:`SLACK` of the prior's total) there
puts in what neither the data nor the prior support — weights the training never moved from a
random start, or Adam's per-parameter scaling, whose steps leave the span of ``Pᵀ`` (measured, CLI
defaults, noise-free: Adam 13× the prior's on heat_1d, 5.3× on heat_2d; SIP 0.98 and 1.00, HIG
0.09–1.0) — and :func:`unseen_energy` says so. Nothing is computed for an operator without a
spectral basis (a time-stepping or reversible one: the wave scenes see every direction).
"""

from __future__ import annotations

import numpy as np
import torch

from ..physics.capabilities import modal_basis

#: gains below this fraction of the largest count as unseen on noise-free data (rounding)
FLOOR = 1e-12
#: the predictions' unseen energy a warning tolerates, in units of the prior's (module docstring)
FACTOR = 2.0
#: and in units of the prior's total energy
SLACK = 0.01


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
        return record, None
    ratio, unseen = pred / max(prior, np.finfo(float).tiny), problem.N - int(keep.sum())
    return record, (f"the predictions carry {ratio:.3g}× the prior's energy in the {unseen} directions the "
                    f"physics cannot see (gain below {max(problem.noise, FLOOR):g} of the largest): the data "
                    "cannot have put it there and the prior holds less, so it adds to x_err (Adam's "
                    "per-parameter scaling, for one, moves those directions)")


@torch.no_grad()
def amplitude(problem, model, test: tuple, seed: int) -> float:
    """``√(mean ‖x̂‖² / mean ‖x_ref‖²)``: the predictions' rms amplitude in units of the prior's (the
    reference as in :func:`of_predictions`), for any operator."""
    from .trainset import TEST_DATA, seed_stream

    x, _, y_t = test
    if x is None:
        x = problem.sample(len(y_t), seed_stream(seed, TEST_DATA))[0]
    xhat = model(y_t).double().cpu().numpy()
    ref = float(np.mean(np.sum(np.asarray(x, dtype=float) ** 2, axis=1)))
    return float(np.sqrt(np.mean(np.sum(xhat**2, axis=1)) / max(ref, np.finfo(float).tiny)))


@torch.no_grad()
def of_predictions(problem, model, test: tuple, seed: int) -> tuple[dict | None, str | None]:
    """:func:`unseen_energy` of ``model``'s predictions on a trainer's ``test = (x or None, y, y
    tensor)``; without ``x`` the reference is as many prior samples (the test stream of ``seed``)."""
    from .trainset import TEST_DATA, seed_stream

    x, _, y_t = test
    if x is None:
        x = problem.sample(len(y_t), seed_stream(seed, TEST_DATA))[0]
    return unseen_energy(problem, model(y_t).double().cpu().numpy(), x)
