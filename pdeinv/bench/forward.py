"""Forward accuracy against cost: every backend over a ladder of meshes and step counts.

The initial field is the first Laplace eigenfunction ``u₀ = Π sin(π x_d)`` on the unit
square (interval), ``λ = dim · π²``, whose exact solutions are

    heat:  u(T) = exp(−κ λ T) u₀,        wave (v₀ = 0):  u(T) = cos(c √λ T) u₀,

and the error is the relative L²(Ω) error of the computed final field against the
nodal interpolant of ``u(T)`` (space and time discretization together). The time is
the minimum over ``repeats`` forward runs on a batch of ``batch`` columns, and
``setup_s`` the one-off build (factorization, eigenvectors). A backend that refuses a
setting (e.g. the modal backend needing too many modes) is recorded as refused.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np

from .. import mesh as meshes
from ..forms import discretize
from ..physics import Heat, Leapfrog, Wave
from ..physics.heat_backends import weyl_count
from ..physics.modes import TooManyModes
from .timing import best


def modal(d, c, k):
    """BE modal backend, refused up front when Weyl's law predicts more than N/2 live modes.

    (Building it would compute thousands of eigenpairs only to refuse; the same
    estimate as :func:`pdeinv.physics.heat_backends.choose`.)
    """
    dt, tol = c["T"] / k, 1e-14
    rho = tol ** (1.0 / k)
    k_est = weyl_count(SimpleNamespace(dim=d.dim, measure=d.measure), (1.0 - rho) / rho / (dt * c["kappa"]))
    if k_est > d.N / 2:
        raise ValueError(f"modal: Weyl's law predicts ~{k_est:.0f} of {d.N} modes above tol (> N/2)")
    return Heat(d.M, d.K, c["kappa"], c["T"], k, "be", "modal")


#: backend name -> (discretization, settings, steps) -> operator; per physics type
HEAT_BACKENDS = {
    "BE steps": lambda d, c, k: Heat(d.M, d.K, c["kappa"], c["T"], k, "be", "steps"),
    "CN steps": lambda d, c, k: Heat(d.M, d.K, c["kappa"], c["T"], k, "cn", "steps"),
    "BE modal": modal,
}
def leapfrog(d, c, k):
    """Explicit leapfrog with the lumped P1 mass; below its CFL step count the point is 'refused'."""
    if c["element"] != "P1":
        raise ValueError(f"leapfrog needs a lumped mass, offered for P1 only (element={c['element']!r})")
    return Leapfrog(discretize(d.basis.mesh, "P1", lumped=True).M, d.K, c["c"], c["T"], k)


WAVE_BACKENDS = {"Newmark": lambda d, c, k: Wave(d.M, d.K, c["c"], c["T"], k), "leapfrog": leapfrog}


def exact_factor(op, dim: int) -> float:
    """``u(T)/u₀`` for the first eigenfunction (continuous problem)."""
    lam = dim * np.pi**2
    if isinstance(op, Heat):
        return float(np.exp(-op.kappa * lam * op.t_end))
    return float(np.cos(op.c * np.sqrt(lam) * op.t_end))


def applies(problem) -> str | None:
    """``None`` if the analytic ladder applies to ``problem``, else why not."""
    cfg = problem.settings
    if type(problem.operator) not in (Heat, Wave, Leapfrog):
        return f"no analytic solution for a {type(problem.operator).__name__} operator"
    if "n" not in cfg or cfg.get("mesh"):
        return "the analytic mode needs the built-in interval / unit square / unit cube mesh (setting n)"
    return None


def ladder(problem, ns, steps, repeats: int = 3, batch: int = 16) -> dict:
    """``{"points": [...], "reason": ...}``; each point: backend, n, steps, N, error, time_s, setup_s."""
    why = applies(problem)
    if why:
        return {"points": [], "skipped": why}
    cfg, dim = problem.settings, problem.disc.dim
    backends = HEAT_BACKENDS if isinstance(problem.operator, Heat) else WAVE_BACKENDS
    points = []
    for n in ns:
        m = {1: meshes.interval, 2: meshes.unit_square, 3: meshes.unit_cube}[dim](n)  # the scene's dimension
        disc = discretize(m, cfg["element"])
        x0 = np.prod(np.sin(np.pi * disc.points), axis=0)
        X = np.tile(x0, (batch, 1))
        for name, build in backends.items():
            for k in steps:
                row = {"backend": name, "n": n, "steps": k, "N": disc.N}
                try:
                    t = time.perf_counter()
                    op = build(disc, cfg, k)
                    row["setup_s"] = time.perf_counter() - t
                except (TooManyModes, ValueError) as err:
                    points.append({**row, "outcome": "refused", "message": str(err)})
                    continue
                target = exact_factor(op, dim) * x0
                y = op.forward(x0[None])
                row["error"] = float(disc.relative_error(y, target[None])[0])
                row["time_s"] = best(lambda op=op: op.forward(X), repeats)
                points.append({**row, "outcome": "ok"})
    return {"points": points, "batch": batch}


def default_ladder(problem, quick: bool) -> tuple[list[int], list[int]]:
    """Meshes ``n/4, n/2, n`` and steps ``steps/10 … 3·steps`` (quick: ``n/2, n`` and ``steps/2, steps``).

    No mesh finer than the scene's own: at 2n (3969 unknowns for heat_2d) the modal
    setup alone (a few hundred eigenpairs by shift-invert Lanczos) took minutes here.
    """
    n, k = int(problem.settings.get("n", 8)), int(problem.settings.get("steps", 10))
    if quick:
        return sorted({max(2, n // 2), n}), sorted({max(1, k // 2), k})
    return sorted({max(2, n // 4), max(2, n // 2), n}), sorted({max(1, k // 10), max(1, k // 3), k, 3 * k})


def pareto(points: list[dict]) -> list[int]:
    """Indices of the ok points no other point beats in both time and error."""
    ok = [(i, p["time_s"], p["error"]) for i, p in enumerate(points) if p.get("outcome") == "ok"]
    return [i for i, t, e in ok if not any(t2 <= t and e2 <= e and (t2, e2) != (t, e) for _, t2, e2 in ok)]
