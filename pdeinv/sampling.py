"""Random initial fields for training and testing.

``gaussian_bumps`` draws ``x(p) = Σ_{j<m} a_j exp(−|p − c_j|² / (2 s_j²))`` at the
given points with, per sample and bump independently,

    m = bumps (default 3),  a_j ~ U(−1, 1),
    c_j ~ U(box shrunk by 10% on each side),  s_j ~ U(0.05, 0.15) · diam(box),

where ``box`` is the bounding box of the points. With homogeneous Dirichlet
conditions the values at the boundary are dropped (condensation), which leaves
a small jump for bumps near the boundary; the physics smooths it at once.
"""

from __future__ import annotations

import numpy as np


def gaussian_bumps(points: np.ndarray, n: int, rng: np.random.Generator, bumps: int = 3,
                   width=(0.05, 0.15)) -> np.ndarray:
    """``(n, N)`` fields at ``points`` (shape ``(dim, N)``), distribution as above."""
    lo, hi = points.min(axis=1), points.max(axis=1)
    span = hi - lo
    diam = float(np.linalg.norm(span))
    dim = points.shape[0]
    a = rng.uniform(-1.0, 1.0, size=(n, bumps))
    c = lo + span * rng.uniform(0.1, 0.9, size=(n, bumps, dim))
    s = diam * rng.uniform(*width, size=(n, bumps))
    d2 = ((points.T[None, None, :, :] - c[:, :, None, :]) ** 2).sum(-1)  # (n, bumps, N)
    return np.einsum("nb,nbp->np", a, np.exp(-d2 / (2 * s[:, :, None] ** 2)))


def add_noise(Y: np.ndarray, level: float, rng: np.random.Generator) -> np.ndarray:
    """``y + level · rms(y) · ε`` per sample, ``ε ~ N(0, I)`` (relative noise level)."""
    if level == 0:
        return Y
    rms = np.sqrt((Y**2).mean(axis=1, keepdims=True))
    return Y + level * rms * rng.standard_normal(Y.shape)
