"""What a run's problem *is*, in a few numbers: one fixed draw of its prior and its observations.

A run records its problem by name (or module path) and settings; the module behind that name may be edited
after the run (another κ, mesh or sampler). :func:`fingerprint` reduces the problem to its sizes and to
three numbers each of one seeded prior draw ``x₀`` and of its noise-free observations ``y₀ = P x₀``: the
norm and two fixed random projections ``wᵢ·x₀``. :func:`changed` compares a rebuilt problem with the
recorded numbers, to a relative ``RTOL`` of each vector's norm (float64 solves on other machines and
thread counts agree to far better than 1e-6; an edited setting moves them by far more).
"""

from __future__ import annotations

import numpy as np

#: the relative tolerance of a fingerprint's projections: well above rounding (1e-12 across BLAS and
#: thread counts), well below what any edited setting moves (1e-3 and more)
RTOL = 1e-6
_SEED = 20260101  # the draw and the projections: fixed, so every machine takes the same


def _numbers(v: np.ndarray) -> list[float]:
    w = np.random.default_rng(_SEED).standard_normal((2, v.size))
    return [float(np.linalg.norm(v)), *map(float, w @ v)]


def fingerprint(problem) -> dict:
    """``{"unknowns": N, "observations": m, "x": [‖x₀‖, w₁·x₀, w₂·x₀], "y": [...]}`` of ``problem``."""
    x0 = problem.draws(1, np.random.default_rng(_SEED))
    y0 = np.asarray(problem.operator.forward(x0), dtype=float)
    return {"unknowns": int(problem.N), "observations": int(problem.operator.n_out),
            "x": _numbers(x0.ravel()), "y": _numbers(y0.ravel())}


def _apart(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / max(abs(a[0]), abs(b[0]), np.finfo(float).tiny))


def changed(problem, recorded: dict) -> str | None:
    """``None`` when ``problem`` has the recorded fingerprint, else what differs, in words."""
    now = fingerprint(problem)
    for key, what in (("unknowns", "unknowns"), ("observations", "observations")):
        if now[key] != recorded.get(key):
            return f"it now has {now[key]} {what}, the run's had {recorded.get(key)}"
    for key, what in (("x", "its prior's fixed draw"), ("y", "its observations of a fixed field")):
        gap = _apart(now[key], recorded.get(key, [np.nan] * 3))
        if not gap <= RTOL:
            return f"{what} moved by {gap:.2g} of their norm"
    return None
