"""Is a posterior calibrated? Coverage, credible balls and simulation-based calibration on test rows.

For held-out pairs ``(x, y)`` that no part of the posterior saw:

* **coverage** at level α: the fraction of (row, node) pairs whose true value lies in the central
  interval (calibrated: ≈ α);
* **ball coverage**: the fraction of rows with ``‖x − μ‖_M`` within the credible L²(Ω) ball's radius;
* **SBC** (Talts et al. 2018): the rank of the truth among ``K`` posterior samples is uniform on
  ``0…K`` when the posterior is calibrated; jittered ranks ``(r + U)/(K + 1)`` are compared with U(0, 1)
  by a Kolmogorov–Smirnov test, for two statistics per row: one node drawn at random, and the field's
  mean over the domain ``1ᵀM x / 1ᵀM 1``. A p-value below 0.05 says the samples are miscalibrated;
* **width**: the mean width of the central intervals (sharpness: smaller is better at equal coverage).
"""

from __future__ import annotations

import numpy as np

#: the levels of the per-node coverage report
LEVELS = (0.5, 0.9, 0.95)
#: posterior samples per test row for SBC (ranks 0…K)
SBC_SAMPLES = 99
#: test rows whose posterior samples are drawn at a time (a chunk's draws: SBC_ROWS·K·N numbers)
SBC_ROWS = 32


def _ks(u: np.ndarray) -> float:
    """The Kolmogorov–Smirnov p-value of ``u`` against U(0, 1), by Stephens' (1970) approximation
    ``Q_KS((√n + 0.12 + 0.11/√n) D)`` (within 0.02 of scipy.stats.kstest from n = 20 on; scipy.special, not
    scipy.stats, whose import took 1.1 s of a 3-s run)."""
    from scipy.special import kolmogorov

    u = np.sort(np.asarray(u, dtype=float))
    n = len(u)
    i = np.arange(1, n + 1)
    d = max(float(np.max(i / n - u)), float(np.max(u - (i - 1) / n)))
    root = np.sqrt(n)
    return float(kolmogorov((root + 0.12 + 0.11 / root) * d))


def _ranks(truth: np.ndarray, draws: np.ndarray, rng) -> np.ndarray:
    """Jittered normalized ranks of ``truth`` ``(B,)`` among ``draws`` ``(B, K)``."""
    below = (draws < truth[:, None]).sum(axis=1)
    ties = (draws == truth[:, None]).sum(axis=1)
    rank = below + np.floor(rng.uniform(size=len(truth)) * (ties + 1))
    return (rank + rng.uniform(size=len(truth))) / (draws.shape[1] + 1)


def report(posterior, mean: np.ndarray, x: np.ndarray, mass=None, seed: int = 0,
           samples: int = SBC_SAMPLES) -> dict:
    """The diagnostics (module docstring) of ``posterior`` (a :class:`~.conformal.Calibration`) whose
    network predicted ``mean`` for test rows with true fields ``x`` (both ``(B, N)``)."""
    mean, x = np.atleast_2d(mean), np.atleast_2d(x)
    out = {"rows": len(x)}
    for level in LEVELS:
        lo, hi = posterior.interval(mean, level)
        out[f"coverage_{round(100 * level)}"] = float(np.mean((lo <= x) & (x <= hi)))
        if level == 0.9:
            out["width_90"] = float(np.mean(hi - lo))
    dist = x - mean
    norms = np.sqrt(np.einsum("bi,bi->b", dist, dist if mass is None else (mass @ dist.T).T))
    out["ball_coverage_90"] = float(np.mean(norms <= posterior.ball_radius(0.9, mass)))
    rng = np.random.default_rng(seed)
    pick = posterior.picks(len(x), samples, seed=seed + 1)  # the draws of posterior.samples(mean, …)
    node = rng.integers(x.shape[1], size=len(x))
    weights = np.ones(x.shape[1]) if mass is None else np.asarray(mass @ np.ones(x.shape[1])).ravel()
    weights = weights / weights.sum()
    at_node, means = np.empty((len(x), samples)), np.empty((len(x), samples))
    for start in range(0, len(x), SBC_ROWS):  # (B, K, N) at once: 0.8 GB for 256 rows of 3 969 nodes
        rows = slice(start, start + SBC_ROWS)
        draws = posterior.drawn(mean[rows], pick[rows])
        at_node[rows] = draws[np.arange(len(draws)), :, node[rows]]
        means[rows] = draws @ weights
    out["sbc_p_node"] = _ks(_ranks(x[np.arange(len(x)), node], at_node, rng))
    out["sbc_p_mean"] = _ks(_ranks(x @ weights, means, rng))
    return out
