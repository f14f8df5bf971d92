"""Heat equation ``M u' + (κ K + C) u = 0``: the θ-scheme map to the final field, ``P = (A⁻¹B)ⁿ``.

θ=1 backward Euler ('be', L-stable, default), θ=½ Crank–Nicolson ('cn'); the step and its
exact transpose are :class:`.schemes.Theta`, the loop is the one :class:`.propagator.Propagator`
with a :class:`.propagator.FinalField`. ``C`` is an optional matrix added to ``κK``: convection
(advection–diffusion, not symmetric) or a reaction ``C = rM`` (symmetric).

How ``P`` is applied is chosen by :meth:`~.propagator.Propagator.compile` (``backend``): time
stepping, a dense matrix, a truncated SVD, or — whenever the scheme's matrices are symmetric,
with or without ``C`` — the modal form ``P = Φ diag(r(dt μ)ⁿ) Φᵀ M`` over ``L φ = μ M φ``
(:mod:`.modal`); ``'auto'`` by the cost of a training run (:func:`.compiled.plan`), sizing the
modal basis by Weyl's law. ``Heat.choice`` says which and why.
"""

from __future__ import annotations

import numpy as np

from .._checks import choice, count, positive
from ..fem.solvers import default_solver, solver_for
from .backends.modal import weyl_count
from .backends.modes import largest_eigenvalue
from .propagator import FinalField, Propagator
from .schemes import Theta

SCHEMES = {"be": 1.0, "cn": 0.5}


class Heat(Propagator):
    """Final field of the heat equation after ``steps`` θ-scheme steps over ``[0, T]``.

    ``M``, ``K``: condensed mass and stiffness (sparse, symmetric); ``scheme``: 'be' or 'cn';
    ``backend``: 'auto', 'steps', 'modal', 'dense', 'svd' or a backend object; ``solver``: factory
    ``A -> object with solve`` (default:
    :func:`~pdeinv.fem.solvers.default_solver` for a ``dim``-D mesh: AMG-CG above its crossover, else
    Cholesky if cholespy is installed, else SuperLU); ``tol``: relative amplification below which
    modes are dropped (modal backend); ``measure``: |Ω|, for Weyl's count of the modes;
    ``C``: a matrix added to ``κK`` (convection: then no modal form; a reaction ``rM``: modal).
    """

    def __init__(self, M, K, kappa=0.01, T=1.0, steps=100, scheme="be", backend="auto",
                 solver=default_solver, tol=1e-14, measure=1.0, dim=2, C=None):
        self.M, self.K, self.C = M, K, C
        self.kappa = positive(kappa, "kappa")
        self.t_end = positive(T, "T")
        steps = count(steps, "steps")
        self.scheme_name = choice(scheme, "scheme", tuple(SCHEMES))
        self.theta = SCHEMES[scheme]
        self.tol = positive(tol, "tol")
        self.measure, self.dim = measure, dim
        solver = solver_for(dim) if solver is default_solver else solver  # AMG above its crossover
        L = self.kappa * K if C is None else self.kappa * K + C
        super().__init__(Theta(M, L, self.t_end / steps, self.theta, solver), FinalField(M.shape[0], steps),
                         steps, M)
        if isinstance(backend, str):
            self.compile(backend)
        else:
            self._use(backend, f"backend object {type(backend).__name__}")

    #: the θ-step (one factorization of ``A``), shared with every sensor run of this operator
    stepper = property(lambda self: self.scheme)

    def count_modes(self, mu: float) -> float:
        """How many eigenvalues of the scheme's ``L φ = μ M φ`` lie below ``μ``: counted exactly by
        Sylvester's inertia (:func:`.modes.count_below`, one sparse LU) where the matrices are
        symmetric and the mesh is beyond the dense eigensolve (``modes.DENSE_MAX``), else Weyl's
        count of the Laplacian's eigenvalues below ``μ/κ`` (an over-count, on the safe side).
        Weyl's law, a continuum count, over-counts coarse 3-D meshes by 2-3x (heat_3d n=24: 3 963
        against 1 875), which made the modal basis look unaffordable or sized its eigensolve 2x."""
        exact = self.exact_count(mu)
        return weyl_count(self, mu / self.kappa) if exact is None else float(exact)

    def max_gain_squared(self) -> float | None:
        """``λ_max(P*P) = max g²`` over all modes (``|r(dt μ)|ⁿ`` is extremal at the lowest or the
        highest eigenvalue of ``Lφ = μMφ``); ``None`` when not symmetric (no modal picture)."""
        if not self.symmetric:
            return None
        import scipy.sparse.linalg as sla

        sc = self.scheme
        lo = float(sla.eigsh(sc.L.tocsc(), 1, sc.M.tocsc(), sigma=0, which="LM")[0][0])
        hi = largest_eigenvalue(sc.M, sc.L)
        return float(max(sc.gain(lo) ** (2 * self.steps), sc.gain(hi) ** (2 * self.steps)))

    def amplification(self, lam):
        """``r(dtκλ)ⁿ``: what the whole run does to a mode ``Kφ = λMφ`` (without ``C``)."""
        return self.scheme.gain(self.kappa * np.asarray(lam)) ** self.steps

    def __repr__(self):
        return (f"Heat(N={self.n_in}, kappa={self.kappa}, T={self.t_end}, steps={self.steps}, "
                f"scheme={self.scheme_name!r}, backend={self.kind!r})")
