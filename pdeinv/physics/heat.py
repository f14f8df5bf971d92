"""Heat equation ``M u' + (κ K + C) u = 0``: the θ-scheme map to the final field, ``P = (A⁻¹B)ⁿ``.

θ=1 backward Euler ('be', L-stable, default), θ=½ Crank–Nicolson ('cn'); the step and
its exact transpose are :class:`.schemes.Theta`. ``C`` is an optional convection matrix
(advection–diffusion, not symmetric); without it every matrix is symmetric and the
modal backend is available. Two backends give the same ``P`` (:mod:`.heat_backends`):

* ``Stepping``: n solves with one factorization, all batch columns at once;
* ``Modal``: with ``K Φ = M Φ Λ``, ``ΦᵀMΦ = I``, the scheme is diagonal,
  ``P = Φ diag(r(dtκλ)ⁿ) Φᵀ M`` with ``r(z) = (1 − (1−θ)z)/(1 + θz)``; modes with
  ``|r|ⁿ < tol·max|r|ⁿ`` are dropped, so P is exact to ``tol`` relative.

``backend='auto'`` estimates both costs and takes the cheaper (see
:func:`.heat_backends.choose`); ``Heat.choice`` says which and why.
"""

from __future__ import annotations

from functools import cached_property

from .._checks import choice, count, positive
from ..solvers import default_solver, solver_for
from .base import LinearOperator
from .heat_backends import BACKENDS, amplification, choose
from .modes import largest_eigenvalue
from .propagator import Propagator, Records
from .schemes import Theta

SCHEMES = {"be": 1.0, "cn": 0.5}


class Heat(LinearOperator):
    """Final field of the heat equation after ``steps`` θ-scheme steps over ``[0, T]``.

    ``M``, ``K``: condensed mass and stiffness (sparse, symmetric); ``scheme``:
    'be' or 'cn'; ``backend``: 'auto', 'steps', 'modal' or a backend object;
    ``solver``: factory ``A -> object with solve`` (default: :func:`~pdeinv.solvers.default_solver`
    for a ``dim``-D mesh: AMG-CG above its crossover, else Cholesky if cholespy is installed,
    else SuperLU); ``tol``: relative amplification below which
    modes are dropped (modal backend);
    ``measure``: |Ω|, used by the auto cost estimate (Weyl's law);
    ``C``: convection matrix added to ``κK`` (then stepping only).
    """

    def __init__(self, M, K, kappa=0.01, T=1.0, steps=100, scheme="be", backend="auto",
                 solver=default_solver, tol=1e-14, measure=1.0, dim=2, C=None):
        self.M = self.mass = M
        self.K, self.C = K, C
        self.kappa = positive(kappa, "kappa")
        self.t_end = positive(T, "T")
        self.steps = count(steps, "steps")
        self.scheme = choice(scheme, "scheme", tuple(SCHEMES))
        self.theta = SCHEMES[scheme]
        self.dt = self.t_end / self.steps
        self.tol = positive(tol, "tol")
        self.solver = solver_for(dim) if solver is default_solver else solver  # AMG above its crossover
        self.n_in = self.n_out = M.shape[0]
        self.measure, self.dim = measure, dim
        if isinstance(backend, str):
            backend = choice(backend, "backend", ("auto", *BACKENDS))
            if C is not None and backend == "modal":  # (dense and svd work for any operator)
                raise ValueError("backend='modal' needs a symmetric operator and C (convection) makes it "
                                 "non-symmetric; allowed: backend='steps' or 'auto'")
            self.backend, self.choice = choose(self) if backend == "auto" else (
                BACKENDS[backend](self), f"backend={backend!r} requested")
        else:
            self.backend, self.choice = backend, f"backend object {type(backend).__name__}"

    @cached_property
    def stepper(self) -> Theta:
        """The θ-step (one factorization of ``A``), shared by the stepping backend and sensor runs."""
        L = self.kappa * self.K if self.C is None else self.kappa * self.K + self.C
        return Theta(self.M, L, self.dt, self.theta, self.solver)

    output_space = "field"  # capabilities (pdeinv.physics.capabilities): observes a field, measured by M
    symmetric = property(lambda self: self.C is None)
    modes = property(lambda self: self.backend if hasattr(self.backend, "synth") else None)

    def sensors(self, S, record_every: int = 1) -> Propagator:
        """Sensor time series ``S u`` every ``record_every`` steps (always time-stepping)."""
        return Propagator(self.stepper, Records(S, self.n_in, self.steps, record_every), self.steps, self.M)

    def max_gain_squared(self) -> float | None:
        """``λ_max(P*P) = max g²`` over all modes (``|r|ⁿ`` is extremal at the lowest or the
        highest eigenvalue of ``Kφ = λMφ``); ``None`` with convection (no modal picture)."""
        if not self.symmetric:
            return None
        import scipy.sparse.linalg as sla

        lam_lo = float(sla.eigsh(self.K.tocsc(), 1, self.M.tocsc(), sigma=0, which="LM")[0][0])
        lam_hi = largest_eigenvalue(self.M, self.K)
        return float(max(self.amplification(lam_lo) ** 2, self.amplification(lam_hi) ** 2))

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
