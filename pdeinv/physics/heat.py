"""Heat equation ``M u' + κ K u = 0``: the θ-scheme propagator and its exact adjoint.

One step of the θ-scheme is ``A uⁿ⁺¹ = B uⁿ`` with

    A = M + θ dt κ K,    B = M − (1−θ) dt κ K,

θ=1 backward Euler ('be', L-stable, default), θ=½ Crank–Nicolson ('cn'). The
forward map to the final field is ``P = (A⁻¹B)ⁿ`` and, A and B being symmetric,
its transpose is ``Pᵀ = (B A⁻¹)ⁿ``: the same factorization, no trajectory.

Two backends give the same ``P`` (see :mod:`.heat_backends`):

* ``Stepping``: n solves with one factorization, all batch columns at once;
* ``Modal``: with ``K Φ = M Φ Λ``, ``ΦᵀMΦ = I``, the scheme is diagonal,
  ``P = Φ diag(r(dtκλ)ⁿ) Φᵀ M`` with ``r(z) = (1 − (1−θ)z)/(1 + θz)``; modes with
  ``|r|ⁿ < tol·max|r|ⁿ`` are dropped, so P is exact to ``tol`` relative.

``backend='auto'`` estimates both costs and takes the cheaper (see
:func:`.heat_backends.choose`); ``Heat.choice`` says which and why.
"""

from __future__ import annotations

from .._checks import choice, count, positive
from ..solvers import default_solver
from .base import LinearOperator
from .heat_backends import BACKENDS, amplification, choose

SCHEMES = {"be": 1.0, "cn": 0.5}


class Heat(LinearOperator):
    """Final field of the heat equation after ``steps`` θ-scheme steps over ``[0, T]``.

    ``M``, ``K``: condensed mass and stiffness (sparse, symmetric); ``scheme``:
    'be' or 'cn'; ``backend``: 'auto', 'steps', 'modal' or a backend object;
    ``solver``: factory ``A -> object with solve`` (default: Cholesky if cholespy
    is installed, else SuperLU); ``tol``: relative amplification below which
    modes are dropped (modal backend);
    ``measure``: |Ω|, used by the auto cost estimate (Weyl's law).
    """

    def __init__(self, M, K, kappa=0.01, T=1.0, steps=100, scheme="be", backend="auto",
                 solver=default_solver, tol=1e-14, measure=1.0, dim=2):
        self.M, self.K = M, K
        self.kappa = positive(kappa, "kappa")
        self.t_end = positive(T, "T")
        self.steps = count(steps, "steps")
        self.scheme = choice(scheme, "scheme", tuple(SCHEMES))
        self.theta = SCHEMES[scheme]
        self.dt = self.t_end / self.steps
        self.tol = positive(tol, "tol")
        self.solver = solver
        self.n_in = self.n_out = M.shape[0]
        self.measure, self.dim = measure, dim
        if isinstance(backend, str):
            backend = choice(backend, "backend", ("auto", *BACKENDS))
            self.backend, self.choice = choose(self) if backend == "auto" else (
                BACKENDS[backend](self), f"backend={backend!r} requested")
        else:
            self.backend, self.choice = backend, f"backend object {type(backend).__name__}"

    def amplification(self, lam):
        """``r(dtκλ)ⁿ``: what the whole run does to a mode of eigenvalue ``λ``."""
        return amplification(self.dt * self.kappa * lam, self.theta) ** self.steps

    def _forward(self, X):
        return self.backend.forward(X)

    def _adjoint(self, R):
        return self.backend.adjoint(R)

    def __repr__(self):
        return (f"Heat(N={self.n_in}, kappa={self.kappa}, T={self.t_end}, steps={self.steps}, "
                f"scheme={self.scheme!r}, backend={self.backend.name!r})")
