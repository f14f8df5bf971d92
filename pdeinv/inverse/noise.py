"""Noise levels of observations: the variance a known level implies, and an estimate when it is unknown.

The problems' noise model (:func:`pdeinv.problem.sampling.add_noise`) is relative:
``y = P x + δ · rms(P x) · ε`` with ``ε ~ N(0, I)``. Averaged over a data set
every observation component then carries the noise variance

    σ² = δ² · mean(rms(P x)²) = δ²/(1 + δ²) · mean(y²)          (:func:`noise_variance`)

(``mean(y²) = (1 + δ²) mean(rms(Px)²)`` in expectation).

**Estimate** (:func:`estimate_noise`, Gavish & Donoho, *The optimal hard threshold for
singular values is 4/√3*, IEEE Trans. Inf. Theory 2014, eq. (4)): the centred data
matrix ``Ȳ`` (``n × m``) is a low-rank signal plus white noise. The singular values
of the noise part follow the Marchenko–Pastur law, so when the signal occupies
fewer than half of the ``min(n, m)`` directions the *median* singular value is a
noise singular value:

    σ̂ = s_med / √(max(n, m) · μ_β),     β = min(n, m) / max(n, m),

with ``μ_β`` the median of the Marchenko–Pastur distribution of ratio ``β``. The
relative level follows as ``δ̂ = σ̂ / √(mean(y²) − σ̂²)``. Smooth physics (heat,
sensors of a damped field) keeps the signal rank low; an estimate from data whose
signal fills most directions over-states the noise, and the estimate of noise-free
data is the size of its smallest half of singular values, not zero. An estimate below
:data:`ROUNDING_LEVEL` is float64 rounding, not a noise level, and reads as 0
(noise-free): clean heat_1d observations read 2.5e-16, which passed on as a level would make
``pdeinv classical`` fit a Wiener filter to rounding instead of taking the noise-free
branch the trained network takes.
"""

from __future__ import annotations

import numpy as np
from scipy import integrate, optimize


def noise_variance(y: np.ndarray, noise: float) -> float:
    """``σ² = δ²/(1+δ²) · mean(y²)``: per-component variance of relative noise ``δ`` in ``y``."""
    return float(noise) ** 2 / (1.0 + float(noise) ** 2) * float(np.mean(np.asarray(y) ** 2))


def marchenko_pastur_median(beta: float) -> float:
    """Median of the Marchenko–Pastur law with ratio ``0 < β ≤ 1`` and unit variance."""
    if not 0 < beta <= 1:
        raise ValueError(f"beta={beta!r} is not allowed; expected 0 < beta <= 1")
    lo, hi = (1 - np.sqrt(beta)) ** 2, (1 + np.sqrt(beta)) ** 2

    def density(t):
        return np.sqrt(max((hi - t) * (t - lo), 0.0)) / (2 * np.pi * beta * t)

    def cdf(t):
        return integrate.quad(density, lo, t, limit=200)[0]

    return float(optimize.brentq(lambda t: cdf(t) - 0.5, lo, hi, xtol=1e-12))


#: relative levels below this (1e3 float64 epsilons) are rounding: :func:`estimate_noise` returns 0
ROUNDING_LEVEL = 1e3 * float(np.finfo(np.float64).eps)


class NoSignal(ValueError):
    """Observations in which :func:`estimate_noise` finds nothing but noise."""


def signal_free(level: float, tau: float) -> bool:
    """Whether noise of relative level ``δ = level`` accounts for all of the observations by Morozov's
    principle at ``τ = tau``: ``τ`` times the noise's expected norm ``δ/√(1+δ²)·‖y‖`` reaches ``‖y‖``,
    the residual of the estimate 0, which the principle then accepts: ``τδ ≥ √(1+δ²)``, i.e.
    ``δ ≥ 1/√(τ²−1)`` (2.18 at ``τ = 1.1``). White noise of 40 × 15 reads ``δ̂`` from 3.4 to 7, or no
    level at all (:class:`NoSignal`); noise of level 2 on heat_1d reads 1.9."""
    return tau * level >= np.sqrt(1.0 + level**2)


def estimate_noise(y) -> float:
    """The relative noise level ``δ̂`` of observations ``y`` ``(n, m)``; 0 (noise-free) below
    :data:`ROUNDING_LEVEL` (module docstring); :class:`NoSignal` where the noise's variance reaches
    ``mean(y²)``."""
    y = np.asarray(y, dtype=float)
    if y.ndim != 2 or min(y.shape) < 4:
        raise ValueError(f"estimate_noise: observations of shape {y.shape}; expected (n, m) with n, m >= 4")
    if not np.isfinite(y).all():
        raise ValueError("estimate_noise: the observations hold NaN/Inf values")
    n, m = y.shape
    s = np.linalg.svd(y - y.mean(0), compute_uv=False)[: min(n - 1, m)]  # centring removes one direction
    beta = min(n - 1, m) / max(n - 1, m)
    sigma2 = float(np.median(s)) ** 2 / (max(n - 1, m) * marchenko_pastur_median(beta))
    signal2 = float(np.mean(y**2)) - sigma2
    if not signal2 > 0:
        raise NoSignal("estimate_noise: the observations look like pure noise (no low-rank signal)")
    level = float(np.sqrt(sigma2 / signal2))
    return level if level >= ROUNDING_LEVEL else 0.0


#: the fewest observed directions outside ``range(P)`` that :func:`estimate_noise_outside` reads
MIN_COMPLEMENT = 16


def estimate_noise_outside(y, out) -> float | None:
    """The relative noise level of observations ``y`` ``(n, m)`` read off the directions no ``x`` reaches:
    with ``Q`` an orthonormal basis of ``span(out)`` (``out`` ``(m, r)``: the operator's spectral basis in
    the observation space), white noise puts ``(m − r)σ_i²`` into ``‖(I − QQᵀ) y_i‖²`` and the signal
    nothing, so ``δ²/(1 + δ²) = mean_i ‖(I − QQᵀ)y_i‖² / ((m − r)·mean(y_i²))`` (the convention of
    :func:`pdeinv.problem.sampling.add_noise`) — unbiased, with no model of the signal. ``None`` when fewer
    than
    :data:`MIN_COMPLEMENT` directions lie outside (an invertible operator: use :func:`estimate_noise`).
    Why: it reads 1 % as 0.0100 where :func:`estimate_noise` is ~20 % low, and a Wiener target fitted with
    a level that low keeps pure-noise modes."""
    y = np.asarray(y, dtype=float)
    Q = np.linalg.qr(np.asarray(out, dtype=float))[0]
    m, r = y.shape[1], Q.shape[1]
    if m - r < MIN_COMPLEMENT:
        return None
    rest = y - (y @ Q) @ Q.T
    ratio = float(np.mean((rest**2).sum(1) / ((m - r) * np.maximum((y**2).mean(1), np.finfo(float).tiny))))
    return float(np.sqrt(ratio / (1 - ratio))) if ratio < 1 else float("inf")
