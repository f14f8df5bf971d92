"""The modal compiled kind: a symmetric θ-scheme observed at the final time, diagonalized.

With ``L φ = μ M φ``, ``ΦᵀMΦ = I`` (``L = κK``, or ``κK + C`` for a symmetric ``C`` such as
a reaction ``C = rM``), each θ-step multiplies mode ``i`` by ``r(dt μᵢ) = (1 − (1−θ) dt μᵢ) /
(1 + θ dt μᵢ)`` (:meth:`.schemes.Theta.gain`), so the run is exactly, for the discrete scheme,

    P = (A⁻¹B)ⁿ = Φ diag(g) Φᵀ M,   g = r(dt μ)ⁿ.

Modes with ``|g| < tol·max|g|`` are dropped (compared in logs, so nothing underflows first):
``P`` is then exact to ``tol`` relative. forward ``((X MΦ) g) Φᵀ``, adjoint ``((R Φ) g) (MΦ)ᵀ``
(:class:`.capabilities.Spectral` with ``In = proj = MΦ``, ``out = synth = Φ``). For
Crank–Nicolson ``|r| → 1`` as ``dt μ → ∞``: if the highest mode would still be kept the
truncation is not exact and a ``ValueError`` says so.

Offered where the scheme's own matrices are symmetric (:attr:`.schemes.Theta.symmetric`, one
answer for every caller): :func:`estimate` gives :func:`.compiled.plan` the expected number of
modes and the cost of the eigensolve, and ``plan`` weighs it against stepping, dense and SVD.
"""

from __future__ import annotations

import math

import numpy as np

from ...util.cache import cached
from ..capabilities import Spectral
from ..schemes import Theta
from . import modes as _modes
from .compiled import BLAS_ADVANTAGE
from .modes import largest_eigenvalue, lowest_modes

#: Weyl constants ``ω_d/(2π)^d`` per dimension
WEYL = {1: 1 / math.pi, 2: 1 / (4 * math.pi), 3: 1 / (6 * math.pi**2)}


def weyl_count(domain, lam: float) -> float:
    """Weyl's law: about how many eigenvalues of the Laplacian on ``domain`` (``dim``, ``measure``)
    lie below ``lam``: ``N(λ) ≈ ω_d |Ω| λ^{d/2} / (2π)^d`` (``ω_d`` the unit ball's volume): 1-D
    ``|Ω|√λ/π``, 2-D ``|Ω|λ/(4π)``, 3-D ``|Ω|λ^{3/2}/(6π²)`` (leading terms; over-estimates for
    Dirichlet)."""
    if domain.dim not in WEYL:
        raise ValueError(f"dim={domain.dim!r} is not supported by Weyl's law here; expected 1, 2 or 3")
    return domain.measure * WEYL[domain.dim] * lam ** (domain.dim / 2) + 1


def refused(op) -> str | None:
    """Why ``op`` has no modal form, or None: a θ-scheme with symmetric matrices, final field."""
    if not isinstance(op.scheme, Theta):
        return f"its scheme is {type(op.scheme).__name__}, not a θ-scheme"
    if not op.symmetric:
        return "its matrices are not symmetric (convection, for one)"
    if op.output_space != "field":
        return "it records sensors over time, not the final field"
    return None


def cutoff(op) -> float:
    """The eigenvalue ``μ`` at the cut-off ``|r(dt μ)|ⁿ = tol``, on the damped branch:
    ``r = ρ = tol^{1/n}`` gives ``dt μ = (1 − ρ) / (θρ + 1 − θ)``."""
    rho, th = op.tol ** (1.0 / op.steps), op.scheme.theta
    return max(1.0 - rho, 0.0) / (th * rho + (1.0 - th)) / op.scheme.dt


def estimate(op) -> tuple[float, float] | None:
    """``(k, build flops)`` of the modal kind for ``op``, or None where it is not offered.

    ``k``: the modes expected below the cut-off (``op.count_modes``: Weyl's law for heat), at most
    ``N``. Build (:func:`.modes.route`): a dense generalized eigendecomposition (about ``9N³`` BLAS
    flops) up to ``modes.DENSE_MAX`` unknowns, and up to ``modes.DENSE_EIGH_MAX`` where it is the
    cheaper one; else the block Krylov eigensolve (about ``2k`` shift-invert solves, one step's
    flops each, and :func:`.modes.krylov_flops` BLAS flops), offered only for ``k ≤ N/2`` (it
    refuses more, :class:`~pdeinv.errors.TooManyModes`). ``k`` is exact beyond ``modes.DENSE_MAX``
    (:meth:`pdeinv.physics.Heat.count_modes`: Sylvester's inertia).
    """
    if refused(op):
        return None
    N = op.n_in
    k = min(op.count_modes(cutoff(op)), N)
    guess = math.ceil(1.1 * k + 10)  # the eigensolve's own (Modal)
    how = _modes.route(N, guess)
    if how == "dense":
        return k, 9 * N**3 / BLAS_ADVANTAGE
    if how is None:
        return None
    return k, 2 * guess * op.step_flops() / op.steps + _modes.krylov_flops(N, guess) / BLAS_ADVANTAGE


class Modal(Spectral):
    """The truncated modal form of ``op`` (module docstring): ``lam`` (``μ``), ``Phi``, ``MPhi``, ``g``.

    The modes come from one eigensolve sized by ``op.count_modes`` at the cut-off plus a margin
    (:func:`.modes.lowest_modes`) and are kept in the disk cache (:mod:`pdeinv.util.cache`, kind 'modal',
    key: ``M``, ``L`` and every setting that decides which modes are kept); ``cache=False`` (or
    ``PDEINV_NO_CACHE=1``) recomputes. The basis is M-orthonormal in the scheme's own ``M``.
    """

    name = "modal"

    def __init__(self, op, cache: bool = True):
        why = refused(op)
        if why:
            raise ValueError(f"backend='modal' needs a symmetric operator (a θ-scheme with symmetric "
                             f"matrices, observed at the final time) and {why}; allowed: backend='steps', "
                             "'dense', 'svd' or 'auto'")
        sc, n, log_tol = op.scheme, op.steps, math.log(op.tol)

        def log_g(mu):  # log|r(dt μ)ⁿ|, safe where r underflows or vanishes
            return n * np.log(np.maximum(np.abs(sc.gain(np.asarray(mu))), 1e-300))

        if sc.theta < 1.0:
            top = largest_eigenvalue(sc.M, sc.L)
            if log_g(top) >= log_tol:
                raise ValueError(f"Crank–Nicolson barely damps the highest mode (|r|ⁿ = "
                                 f"{np.exp(log_g(top)):.1e} ≥ tol={op.tol}): the modal backend would need "
                                 "all modes; use backend='steps' or scheme='be'")
        k_guess = math.ceil(1.1 * op.count_modes(cutoff(op)) + 10)  # the count, plus 10% and 10
        # with the exact count of eigenvalues below the absolute cut-off (gain ≥ tol), the Krylov method
        # keeps at least those (the relative cut, gain ≥ tol·max gain, keeps as many or more)
        at_least = op.exact_count(cutoff(op)) or 0
        N = sc.M.shape[0]
        dense = _modes.route(N, k_guess) == "dense"
        settings = {"dt": sc.dt, "theta": sc.theta, "steps": n, "tol": op.tol, "dense": dense, "k": k_guess,
                    "method": "block-krylov/2"}

        def build():  # the lowest mode is the least damped one (|r| decreases on the damped branch)
            lam, Phi = lowest_modes(sc.M, sc.L, log_g, log_tol, k=k_guess, at_least=at_least)
            return {"lam": lam, "Phi": Phi}

        def verify(a):
            lam, Phi = a.get("lam", np.zeros(0)), a.get("Phi", np.zeros((0, 0)))
            if lam.ndim != 1 or len(lam) == 0 or Phi.shape != (N, len(lam)):
                return f"Phi of shape {Phi.shape} for {lam.shape} eigenvalues and {N} unknowns"

        got = cached("modal", {"M": sc.M, "L": sc.L, "settings": settings}, build, verify, cache)
        self.lam, self.Phi = got["lam"], np.ascontiguousarray(got["Phi"])
        self.g = sc.gain(self.lam) ** n
        self.MPhi = np.ascontiguousarray(sc.M @ self.Phi)
        self.In = self.proj = self.MPhi
        self.out = self.synth = self.Phi
        self.mass_out = sc.M
