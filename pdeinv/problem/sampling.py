"""Random initial fields for training and testing: the priors the built-in scenes draw from.

Every sampler is ``sampler(points, n, rng) -> (n, N)``: fields evaluated at ``points``
(``(dim, N)``), any dimension, any mesh. Lengths are relative to the bounding box of the points
(``lo``, ``span = hi − lo``, ``diam = ‖span‖``); with homogeneous Dirichlet conditions the values
at the boundary are dropped (condensation). :data:`PRIORS` maps the ``prior`` setting of the
scenes to them.

* :func:`gaussian_bumps` (``bumps``, the default): ``x(p) = Σ_{j<m} a_j exp(−|p − c_j|²/(2 s_j²))``,
  ``m = 3``, ``a_j ~ U(−1, 1)``, ``c_j ~ U(lo + 0.1 span, hi − 0.1 span)``,
  ``s_j ~ U(0.05, 0.15)·diam``. Smooth and nearly Gaussian in the leading modes: a linear estimator
  is close to optimal for it.
* :func:`boxes` (``boxes``; the SIP paper's heat prior, Holl et al. 2022):
  ``x(p) = Σ_{j<m} a_j 1[|p_d − c_jd| ≤ h_jd ∀d]``, ``m ~ U{4, …, 10}``, ``a_j ~ U(0, 1)``,
  ``c_j ~ U(lo + 0.1 span, hi − 0.1 span)``, half-sides ``h_jd ~ U(1/64, 10/64)·span_d`` (the paper:
  up to 10 cells of 64). Piecewise constant with jumps: far from Gaussian; the conditional mean of
  its fine scales given its coarse ones is nonlinear, which is what a network can learn and a
  linear filter cannot.
* :func:`gaussian_random_field` (``grf``): a stationary Gaussian field with the squared-exponential
  covariance ``exp(−|p − q|²/(2ℓ²))``, ``ℓ = 0.1·diam``, drawn by random Fourier features
  (Rahimi & Recht 2007): ``x(p) = √(2/K) Σ_{k<K} ξ_k cos(ω_k·p + φ_k)``, ``ω_k ~ N(0, ℓ⁻² I)``,
  ``φ_k ~ U(0, 2π)``, ``ξ_k ~ N(0, 1)``, ``K = 512``: exactly Gaussian (given the features), the
  prior for which the linear MMSE *is* the optimal estimator.
"""

from __future__ import annotations

import numpy as np


def _box(points: np.ndarray):
    lo, hi = points.min(axis=1), points.max(axis=1)
    return lo, hi - lo


def gaussian_bumps(points: np.ndarray, n: int, rng: np.random.Generator, bumps: int = 3,
                   width=(0.05, 0.15), chunk: int = 64) -> np.ndarray:
    """``(n, N)`` fields at ``points`` (shape ``(dim, N)``): the ``bumps`` prior (module docstring).

    The same draws as one vectorized expression, evaluated ``chunk`` samples at a time with the
    squared distances summed coordinate by coordinate: memory ``O(chunk·bumps·N)`` whatever ``n``
    (the former ``(n, bumps, N, dim)`` temporary was 3.2 GB for 1024 samples at 65 025 unknowns)."""
    lo, span = _box(points)
    diam = float(np.linalg.norm(span))
    dim = points.shape[0]
    a = rng.uniform(-1.0, 1.0, size=(n, bumps))
    c = lo + span * rng.uniform(0.1, 0.9, size=(n, bumps, dim))
    s = diam * rng.uniform(*width, size=(n, bumps))
    out = np.empty((n, points.shape[1]))
    for i in range(0, n, chunk):
        j = min(i + chunk, n)
        d2 = np.zeros((j - i, bumps, points.shape[1]))
        for d in range(dim):
            d2 += (points[d][None, None, :] - c[i:j, :, d, None]) ** 2
        d2 *= (-0.5 / s[i:j] ** 2)[:, :, None]
        np.exp(d2, out=d2)
        out[i:j] = np.einsum("nb,nbp->np", a[i:j], d2)
    return out


def boxes(points: np.ndarray, n: int, rng: np.random.Generator, count=(4, 10),
          half=(1 / 64, 10 / 64)) -> np.ndarray:
    """``(n, N)`` fields at ``points``: the ``boxes`` prior (module docstring); ``count`` bounds the
    number of boxes (inclusive), ``half`` their half-sides relative to the bounding box."""
    lo, span = _box(points)
    dim, m = points.shape[0], count[1]
    k = rng.integers(count[0], count[1] + 1, size=n)
    a = rng.uniform(0.0, 1.0, size=(n, m)) * (np.arange(m)[None, :] < k[:, None])  # unused boxes: 0
    c = lo + span * rng.uniform(0.1, 0.9, size=(n, m, dim))
    h = span * rng.uniform(*half, size=(n, m, dim))
    x = np.empty((n, points.shape[1]))
    for s in range(0, n, 64):  # (64, m, N) per chunk: memory stays O(m·N) whatever n
        e = slice(s, s + 64)
        inside = np.abs(points[0][None, None, :] - c[e, :, 0, None]) <= h[e, :, 0, None]
        for d in range(1, dim):  # one axis at a time: no (m, N, dim) array
            inside &= np.abs(points[d][None, None, :] - c[e, :, d, None]) <= h[e, :, d, None]
        x[e] = np.einsum("bm,bmn->bn", a[e], inside)
    return x


def gaussian_random_field(points: np.ndarray, n: int, rng: np.random.Generator, length: float = 0.1,
                          features: int = 512) -> np.ndarray:
    """``(n, N)`` fields at ``points``: the ``grf`` prior (module docstring); ``length`` is ``ℓ``
    relative to the bounding box's diameter, ``features`` is ``K``."""
    _, span = _box(points)
    ell = length * float(np.linalg.norm(span))
    dim = points.shape[0]
    out = np.empty((n, points.shape[1]))
    for i in range(n):
        w = rng.standard_normal((features, dim)) / ell
        phase = rng.uniform(0.0, 2 * np.pi, size=(features, 1))
        xi = rng.standard_normal(features)
        out[i] = np.sqrt(2.0 / features) * xi @ np.cos(w @ points + phase)
    return out


#: the ``prior`` setting of the scenes: name -> sampler(points, n, rng)
PRIORS = {"bumps": gaussian_bumps, "boxes": boxes, "grf": gaussian_random_field}


def add_noise(Y: np.ndarray, level: float, rng: np.random.Generator) -> np.ndarray:
    """``y + level · rms(y) · ε`` per sample, ``ε ~ N(0, I)`` (relative noise level)."""
    if level == 0:
        return Y
    rms = np.sqrt((Y**2).mean(axis=1, keepdims=True))
    return Y + level * rms * rng.standard_normal(Y.shape)
