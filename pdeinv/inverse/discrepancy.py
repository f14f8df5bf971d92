"""Root finding for the discrepancy principle, vectorized over the samples.

Solve ``ρ_b(α_b) = t_b`` for every sample ``b`` at once, with ``ρ`` increasing in
α. Work in ``s = log α`` on ``F(s) = log ρ(e^s) − log t`` (nearly linear on the
steep part of the curve) with the Illinois variant of regula falsi: superlinear,
and the bracket never stalls on one side. Each iteration calls ``residual``
once for the whole batch, so the cost is ``2 + iterations`` residual
evaluations (closed form in the modal backend; one warm-started CG solve each
in the matrix-free backend).
"""

from __future__ import annotations

import numpy as np


def discrepancy_alpha(residual, target, lo: float, hi: float, rtol: float = 1e-3,
                      maxiter: int = 60) -> np.ndarray:
    """α per sample with ``residual(α) ≈ target`` to relative ``rtol`` (clipped to ``[lo, hi]``)."""
    target = np.asarray(target, dtype=float)
    B = target.shape[0]
    tiny = np.finfo(float).tiny

    def F(s):
        return np.log(np.maximum(residual(np.exp(s)), tiny)) - np.log(np.maximum(target, tiny))

    a, b = np.full(B, np.log(lo)), np.full(B, np.log(hi))
    fa, fb = F(a), F(b)
    bracketed = (fa < 0) & (fb > 0)
    # out of bracket: target below ρ(lo) → least regularization; above ρ(hi) → most
    outside = np.where(fa >= 0, lo, hi)
    active = bracketed.copy()
    for _ in range(maxiter):
        if not active.any():
            break
        c = np.where(active, b - fb * (b - a) / np.where(active, fb - fa, 1.0), b)
        fc = np.where(active, F(c), fb)
        flip = active & (fc * fb < 0)
        halve = active & ~flip
        a, fa = np.where(flip, b, a), np.where(flip, fb, np.where(halve, fa / 2, fa))
        b, fb = c, fc
        active &= np.abs(fc) > rtol
    return np.where(bracketed, np.exp(b), outside)
