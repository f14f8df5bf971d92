"""Rules choosing the Tikhonov weight α, one per sample, as strategy objects.

A regularized solve hands a rule a :class:`Fit`: the residual function
``ρ(α) = ‖P Δx_α − (y − y₀)‖_{M_out}`` per sample, the observations, the noise
trace ``tr(M_out)`` and the α unit ``scale = λ_max(P*P)`` (``max g²`` in the
modal backend). A rule returns α of shape ``(B,)``. Pass a number for a fixed α.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from numbers import Real
from typing import Protocol, runtime_checkable

import numpy as np

from .._checks import count, positive
from .discrepancy import discrepancy_alpha


@runtime_checkable
class AlphaRule(Protocol):
    """How a regularized solve picks its α: ``select(fit) -> α`` (:class:`FixedAlpha`,
    :class:`RelativeAlpha`, :class:`Discrepancy`, or a user's own object with that method)."""

    def select(self, fit) -> float: ...


@dataclass
class Fit:
    """What a rule may ask of a regularized solve (see module docstring).

    ``scale`` may be given as a zero-argument callable: it is then evaluated only
    if a rule asks (a fixed α needs no unit, and estimating it can cost solves).
    """

    residual: Callable[[np.ndarray], np.ndarray]
    y: np.ndarray
    noise_trace: float
    _scale: float | Callable[[], float]

    @property
    def scale(self) -> float:
        return float(self._scale() if callable(self._scale) else self._scale)


class FixedAlpha:
    """The same absolute α for every sample."""

    def __init__(self, alpha: float):
        self.alpha = positive(alpha, "alpha")

    def select(self, fit: Fit) -> np.ndarray:
        return np.full(fit.y.shape[0], self.alpha)

    def __repr__(self):
        return f"FixedAlpha({self.alpha:g})"


class RelativeAlpha:
    """``α = rel · scale``: relative to the largest ``g²`` (largest eigenvalue of ``P*P``).

    ``rel = ε²`` puts the filter's cut-off ``g² = α`` at amplification ``ε·max g``:
    modes amplified by more than that are recovered with relative bias
    ``α/(g²+α) < ½``, weaker modes are damped.
    """

    def __init__(self, rel: float):
        self.rel = positive(rel, "rel")

    def select(self, fit: Fit) -> np.ndarray:
        return np.full(fit.y.shape[0], self.rel * fit.scale)

    def __repr__(self):
        return f"RelativeAlpha({self.rel:g})"


class Discrepancy:
    """Morozov's discrepancy principle: per sample, the α with ``ρ(α) = τ·‖ε‖`` expected.

    Noise model of :func:`pdeinv.problem.sampling.add_noise`: ``y = P x + δ·rms(Px)·ε``,
    ``ε ~ N(0, I)``. Residuals are measured in the **M-norm of the observation
    space** (the norm of the Tikhonov functional), where white noise has
    ``E‖δ·rms·ε‖²_M = δ²·rms(Px)²·tr(M_out)``. ``rms(Px)`` is estimated from the
    noisy ``y`` as ``rms(y)/√(1+δ²)``. Hence the target

        ρ(α) = τ · δ · rms(y)/√(1+δ²) · √tr(M_out).

    ``ρ`` increases monotonically with α (from the unfittable part of the data at
    α → 0 to ``‖y − y₀‖`` at α → ∞); the root is found by the Illinois (regula
    falsi) method on ``log ρ`` against ``log α`` within
    ``[lo, hi]·scale`` (see :func:`.discrepancy.discrepancy_alpha`). When the
    target lies below ``ρ(lo)`` (the noise was under-stated) ``lo·scale`` is
    used; above ``ρ(hi)`` (nothing to fit), ``hi·scale``.

    **Pooled** (``pooled=True``, default): one α for the whole batch, from the summed residual
    ``Σ_b ρ_b(α)² = Σ_b target_b²``. Per sample (``pooled=False``) the noise norm of one sample
    fluctuates like a χ with as many degrees of freedom as visible modes; with few of them
    (heat_1d: ~18) it exceeds τ times its expectation on a good fraction of samples, α then
    falls until the residual dips below the *actual* noise, i.e. it fits noise through the
    weakest modes (heat_1d at 1 %: one reconstruction 429× the median norm); pooled, the fluctuation
    averages out over the batch (``tests/test_inverse.py``).

    Why ``τ = 1.1`` by default (the theory asks for ``τ > 1``): for a smoothing
    operator most of the noise sits in modes no α can fit, so ``ρ`` is nearly
    flat (≈0.9 of the noise norm) over many decades of small α, and the chi
    fluctuation of the actual noise norm (±6–10% for 60–130 unknowns) would then
    move a ``τ = 1`` root by decades into the under-regularized region (on heat_1d τ = 1.1 stays
    within ~1.1× of the best fixed α's error).
    """

    def __init__(self, noise: float, tau: float = 1.1, lo: float = 1e-16, hi: float = 1e2,
                 rtol: float = 1e-3, maxiter: int = 60, pooled: bool = True):
        self.noise = positive(noise, "noise")
        self.pooled = bool(pooled)
        self.tau = positive(tau, "tau")
        self.lo, self.hi = positive(lo, "lo"), positive(hi, "hi")
        if self.lo >= self.hi:
            raise ValueError(f"lo={lo!r} >= hi={hi!r}; expected lo < hi")
        self.rtol, self.maxiter = positive(rtol, "rtol"), count(maxiter, "maxiter")

    def target(self, fit: Fit) -> np.ndarray:
        rms = np.sqrt((fit.y**2).mean(axis=1)) / np.sqrt(1.0 + self.noise**2)
        return self.tau * self.noise * rms * np.sqrt(fit.noise_trace)

    def select(self, fit: Fit) -> np.ndarray:
        target, lo, hi = self.target(fit), self.lo * fit.scale, self.hi * fit.scale
        if not self.pooled or target.shape[0] == 1:
            return discrepancy_alpha(fit.residual, target, lo, hi, self.rtol, self.maxiter)
        B = target.shape[0]

        def pooled(alpha):  # alpha: (1,) -> the batch's residual norm, (1,)
            return np.sqrt(np.sum(fit.residual(np.full(B, alpha[0])) ** 2))[None]

        alpha = discrepancy_alpha(pooled, np.sqrt(np.sum(target**2))[None], lo, hi, self.rtol, self.maxiter)
        return np.full(B, alpha[0])

    def __repr__(self):
        return f"Discrepancy(noise={self.noise:g}, tau={self.tau:g}, pooled={self.pooled})"


def as_rule(alpha):
    """A number → :class:`FixedAlpha`; an object with ``select(fit)`` → itself."""
    if isinstance(alpha, Real) and not isinstance(alpha, bool):
        return FixedAlpha(alpha)
    if isinstance(alpha, AlphaRule):
        return alpha
    raise ValueError(f"alpha={alpha!r} is not allowed; expected a number > 0 or a rule such as "
                     "Discrepancy(noise) / RelativeAlpha(rel)")
