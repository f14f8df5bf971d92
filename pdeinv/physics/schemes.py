"""One-step time integrators and their exact transposes, on ``(N, b)`` column blocks.

A scheme is a linear map on a *state* ``s`` (a tuple of ``(N, b)`` arrays):

    s₀ = I u₀,      sⱼ = S sⱼ₋₁,      uⱼ = E sⱼ,

``start`` is ``I``, ``step`` is ``S``, ``field`` is ``E``; the transposes are
``start_T`` (``Iᵀ``), ``step_T`` (``Sᵀ``) and ``inject(s̄, w)`` (``s̄ + Eᵀ w``).
:class:`.propagator.Propagator` owns the loop; a scheme only knows one step.
Matrices need not be symmetric: transposes use ``Aᵀ``, ``Bᵀ`` and the solver's
``solve_T``.

* :class:`Theta`, for ``M u' + L u = 0`` (``L = κK`` for heat, ``κK + C`` with
  advection): ``A uⱼ = B uⱼ₋₁``, ``A = M + θ dt L``, ``B = M − (1−θ) dt L``;
  ``Sᵀ r = Bᵀ A⁻ᵀ r``. State ``(u,)``.
* :class:`Newmark` (average acceleration, β = ¼, γ = ½), for ``M u'' + c² K u = 0``:
  the trapezoidal rule on ``(u, v)``, with ``A = M + (c dt/2)² K``, ``B = M − (c dt/2)² K``,

      u' = A⁻¹(B u + dt M v),        v' = 2 (u' − u)/dt − v;

  with ``w = A⁻ᵀ(ū' + s v̄')``, ``s = 2/dt``: ``ū = Bᵀ w − s v̄'``, ``v̄ = dt Mᵀ w − v̄'``.
  Unconditionally stable, energy-conserving, time-reversible (the step with ``−dt``
  undoes it: :meth:`Newmark.step` takes ``sign``).
* :class:`Leapfrog` (central differences) with a lumped (diagonal) mass ``M_L``,
  ``Q = q M_L⁻¹ K``, ``q = (c dt)²``: state ``(uⱼ₋₁, uⱼ)``,
  ``S(p, u) = (u, 2u − p − Q u)``, started from the fictitious ``u₋₁ = u₀ − ½ Q u₀``
  (what ``v₀ = 0`` means for central differences), so every step is the same;
  ``Sᵀ(p̄, ū) = (−ū, p̄ + 2ū − Qᵀ ū)``, ``Iᵀ(p̄, ū) = ū + p̄ − ½ Qᵀ p̄``. Explicit:
  stable iff ``c dt √λ_max < 2`` (checked by the caller, :mod:`.leapfrog`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..solvers import is_symmetric


def transposed(A: sp.spmatrix, symmetric: bool) -> sp.csr_matrix:
    """``Aᵀ`` as CSR, or ``A`` itself when it is symmetric (no copy)."""
    return A if symmetric else A.T.tocsr()


def solve_T(solver, symmetric: bool):
    """The solver's ``A⁻ᵀ``: ``solve_T`` if it has one; ``solve`` for a symmetric ``A``."""
    fn = getattr(solver, "solve_T", None)
    if fn is not None:
        return fn
    if symmetric:
        return solver.solve
    raise ValueError(f"solver {type(solver).__name__} has no solve_T and the matrix is not symmetric; "
                     "use solver=pdeinv.SuperLU")


class _Single:
    """Schemes whose state is the field alone, ``s = (u,)``."""

    def start(self, U):
        return (U,)

    def start_T(self, s):
        return s[0]

    def field(self, s):
        return s[0]

    def inject(self, s, W):
        return (s[0] + W, *s[1:])

    def zeros(self, n: int, b: int):
        return tuple(np.zeros((n, b)) for _ in range(self.width))


class Theta(_Single):
    """θ-scheme step for ``M u' + L u = 0`` (θ = 1 backward Euler, ½ Crank–Nicolson)."""

    width = 1

    def __init__(self, M, L, dt: float, theta: float, solver):
        self.dt, self.theta, self.n = float(dt), float(theta), M.shape[0]
        self.A = (M + theta * dt * L).tocsc()
        self.B = (M - (1.0 - theta) * dt * L).tocsr()
        self.symmetric = is_symmetric(self.A) and is_symmetric(self.B)
        self.lu = solver(self.A)
        self.BT = transposed(self.B, self.symmetric)
        self._solve_T = solve_T(self.lu, self.symmetric)

    def step(self, s):
        return (self.lu.solve(self.B @ s[0]),)

    def step_T(self, s):
        return (self.BT @ self._solve_T(s[0]),)


class Newmark(_Single):
    """Newmark average-acceleration step on ``(u, v)`` for ``M u'' + c² K u = 0`` (module docstring)."""

    width = 2

    def __init__(self, M, K, c: float, dt: float, solver):
        self.dt, self.n = float(dt), M.shape[0]
        q = (c * dt / 2) ** 2
        self.M = M.tocsr()
        self.A = (self.M + q * K).tocsc()
        self.B = (self.M - q * K).tocsr()
        self.symmetric = is_symmetric(self.A) and is_symmetric(self.B) and is_symmetric(self.M)
        self.lu = solver(self.A)
        self.BT, self.MT = transposed(self.B, self.symmetric), transposed(self.M, self.symmetric)
        self._solve_T = solve_T(self.lu, self.symmetric)

    def start(self, U, V=None):
        return (U, np.zeros_like(U) if V is None else V)

    def step(self, s, sign: float = 1.0):
        # v' is formed from the *rounded* u', so u' − u = dt/2 (v + v') holds to rounding;
        # solving for the increment u' − u instead drifts the energy 5x faster (measured)
        U, V = s
        dt = sign * self.dt
        U1 = self.lu.solve(self.B @ U + dt * (self.M @ V))
        return U1, (2.0 / dt) * (U1 - U) - V

    def step_T(self, s):
        Ub, Vb = s
        k = 2.0 / self.dt
        W = self._solve_T(Ub + k * Vb)
        return self.BT @ W - k * Vb, self.dt * (self.MT @ W) - Vb


class Leapfrog:
    """Central-difference step on ``(uⱼ₋₁, uⱼ)`` with a lumped mass (module docstring)."""

    width = 2

    def __init__(self, minv: np.ndarray, K, c: float, dt: float):
        self.dt, self.n = float(dt), K.shape[0]
        self.q = (c * dt) ** 2
        self.minv = np.asarray(minv, dtype=float)[:, None]
        self.K = sp.csr_matrix(K)
        self.symmetric = is_symmetric(self.K)
        self.KT = transposed(self.K, self.symmetric)

    def _Q(self, U):
        return self.q * (self.minv * (self.K @ U))

    def _QT(self, U):
        return self.q * (self.KT @ (self.minv * U))

    def start(self, U):
        return U - 0.5 * self._Q(U), U

    def start_T(self, s):
        P, U = s
        return U + P - 0.5 * self._QT(P)

    def field(self, s):
        return s[1]

    def inject(self, s, W):
        return s[0], s[1] + W

    def zeros(self, n: int, b: int):
        return np.zeros((n, b)), np.zeros((n, b))

    def step(self, s):
        P, U = s
        return U, 2.0 * U - P - self._Q(U)

    def step_T(self, s):
        P, U = s
        return -U, P + 2.0 * U - self._QT(U)
