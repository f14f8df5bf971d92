"""Forward accuracy against cost: the scene itself over a ladder of meshes, step counts and schemes.

From the first Laplace eigenfunction ``u₀ = Π sin(π x_d)`` on the unit interval, square or cube
(``λ = dim · π²``): heat (reaction r ≥ 0) ``u(T) = exp(−(κλ + r) T) u₀``, wave (v₀ = 0)
``u(T) = cos(c √λ T) u₀``; the error is the relative L²(Ω) error of the final field against the
nodal interpolant of ``u(T)`` (space and time together). Each rung is the scene rebuilt by name
with ``n``, ``steps`` and the rung's scheme and backend (:data:`LADDERS`), so a 3-D scene refines
in 3-D; ``setup_s`` is that build, ``time_s`` the best forward of ``batch`` columns. A rung the
scene refuses (too many modes, leapfrog above its stability limit) is recorded with its message.
The ladder applies where every setting is one of a heat or wave scene on the unit box: sensors,
advection, a mesh file or another domain have no exact mode here, and their settings say so.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import TooManyModes
from ..problem.definition import load_problem
from .timing import best

_COMMON = {"element", "T", "steps", "noise", "n", "mesh", "scheme", "backend", "prior", "tol"}
#: physics (named by its defining setting) -> (the settings it may have, {rung: (scheme, backend)}, u(T)/u₀)
LADDERS = {
    "kappa": (_COMMON | {"kappa", "reaction"},
              {"BE steps": ("be", "steps"), "CN steps": ("cn", "steps"), "BE modal": ("be", "modal")},
              lambda c, lam: np.exp(-(c["kappa"] * lam + c.get("reaction", 0.0)) * c["T"])),
    "c": (_COMMON | {"c"}, {"Newmark": ("newmark", "steps"), "leapfrog": ("leapfrog", "steps")},
          lambda c, lam: np.cos(c["c"] * np.sqrt(lam) * c["T"])),
}


def _ladder(problem):
    """``(settings, rungs, factor)`` of the ladder that applies to ``problem``, or a string: why none."""
    cfg = problem.settings
    for key, (allowed, rungs, factor) in LADDERS.items():
        if key in cfg and set(cfg) <= allowed and cfg.get("mesh") is None and "n" in cfg:
            return cfg, rungs, factor
    return (f"no exact mode for {problem.name!r}: its settings ({', '.join(sorted(problem.settings))}) "
            "are not those of a heat or wave scene on the unit interval, square or cube")


def exact_factor(problem) -> float | None:
    """``u(T)/u₀`` of the first eigenfunction (continuous problem), or None: no exact mode."""
    got = _ladder(problem)
    return None if isinstance(got, str) else float(got[2](got[0], problem.disc.dim * np.pi**2))


def ladder(problem, ns, steps, repeats: int = 3, batch: int = 16) -> dict:
    """``{"points": [...]}`` (or ``"skipped"``); a point: backend, n, steps, N, error, time_s, setup_s"""
    got = _ladder(problem)
    if isinstance(got, str):
        return {"points": [], "skipped": got}
    cfg, rungs, _ = got
    keep = {k: v for k, v in cfg.items() if k not in ("n", "steps", "scheme", "backend", "mesh")}
    points = []
    for n in ns:
        for name, (scheme, backend) in rungs.items():
            for k in steps:
                row = {"backend": name, "n": n, "steps": k}
                try:
                    t = time.perf_counter()
                    p = load_problem(problem.name, **keep, scheme=scheme, backend=backend, n=n, steps=k)
                    row.update(N=p.N, setup_s=time.perf_counter() - t)
                except (TooManyModes, ValueError) as err:
                    points.append({**row, "outcome": "refused", "message": str(err)})
                    continue
                x0 = np.prod(np.sin(np.pi * p.disc.points), axis=0)
                y = p.operator.forward(x0[None])
                row["error"] = float(p.disc.relative_error(y, exact_factor(p) * x0[None])[0])
                X = np.tile(x0, (batch, 1))
                row["time_s"] = best(lambda op=p.operator: op.forward(X), repeats)
                points.append({**row, "outcome": "ok"})
    return {"points": points, "batch": batch}


def default_ladder(problem, quick: bool) -> tuple[list[int], list[int]]:
    """Meshes ``n/4, n/2, n`` and steps ``steps/10 … 3·steps`` (quick: ``n/2, n`` and ``steps/2, steps``);
    none finer than the scene's own (at 2n, heat_2d's modal setup alone took minutes)."""
    n, k = int(problem.settings.get("n", 8)), int(problem.settings.get("steps") or 10)  # None: by CFL
    if quick:
        return sorted({max(2, n // 2), n}), sorted({max(1, k // 2), k})
    return sorted({max(2, n // 4), max(2, n // 2), n}), sorted({max(1, k // 10), max(1, k // 3), k, 3 * k})


def pareto(points: list[dict]) -> list[int]:
    """Indices of the ok points no other point beats in both time and error."""
    ok = [(i, p["time_s"], p["error"]) for i, p in enumerate(points) if p.get("outcome") == "ok"]
    return [i for i, t, e in ok if not any(t2 <= t and e2 <= e and (t2, e2) != (t, e) for _, t2, e2 in ok)]
