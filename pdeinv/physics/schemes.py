"""One-step time integrators and their exact transposes, on ``(N, b)`` column blocks.

A scheme is a linear map on a *state* ``s`` (a tuple of ``(N, b)`` arrays): ``s₀ = I u₀``
(``start``), ``sⱼ = S sⱼ₋₁`` (``step``), ``uⱼ = E sⱼ`` (``field``); the transposes are
``start_T`` (``Iᵀ``), ``step_T`` (``Sᵀ``) and ``inject(s̄, w) = s̄ + Eᵀ w``.
:class:`.propagator.Propagator` owns the loop. Matrices need not be symmetric: the
transposes use ``Bᵀ``, ``Mᵀ`` and the solver's ``solve_T`` (plain ``solve`` and no copies
when every matrix is symmetric).

* :class:`Theta`, ``M u' + L u = 0`` (``L = κK``, or ``κK + C`` with advection or reaction): state
  ``(u,)``, ``A u' = B u`` with ``A = M + θ dt L``, ``B = M − (1−θ) dt L``; ``Sᵀ r = Bᵀ A⁻ᵀ r``.
  With ``L`` and ``M`` symmetric each mode ``L φ = μ M φ`` is multiplied by ``r(dt μ)`` per step.
* :class:`Newmark` (average acceleration, β = ¼, γ = ½), ``M u'' + c² K u = 0``: the
  trapezoidal rule on ``(u, v)`` with ``A = M + (c dt/2)² K``, ``B = M − (c dt/2)² K``,
  ``u' = A⁻¹(B u + dt M v)``, ``v' = 2 (u' − u)/dt − v``; transposed, with ``k = 2/dt``
  and ``w = A⁻ᵀ(ū' + k v̄')``: ``ū = Bᵀ w − k v̄'``, ``v̄ = dt Mᵀ w − v̄'``. The step
  with ``−dt`` (``sign=-1``) undoes it.
* :class:`Leapfrog` (central differences, lumped diagonal mass ``M_L``, explicit),
  ``Q = (c dt)² M_L⁻¹ K``: state ``(uⱼ₋₁, uⱼ)``, ``S(p, u) = (u, 2u − p − Qu)`` from the
  fictitious ``u₋₁ = u₀ − ½ Q u₀`` (what ``v₀ = 0`` means here), so every step is alike;
  ``Sᵀ(p̄, ū) = (−ū, p̄ + 2ū − Qᵀū)``, ``Iᵀ(p̄, ū) = ū + p̄ − ½ Qᵀp̄``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..fem.solvers import is_symmetric

#: solve flops per nonzero of ``A`` when the solver does not report its factor's fill (AMG-CG)
FILL_FALLBACK = 10


class Implicit:
    """Shared by the implicit schemes: factor ``A`` once, transposes only where needed."""

    #: the step with ``sign=-1`` undoes it exactly (declared by the scheme: :meth:`Propagator.reverse`)
    reversible = False

    def _factor(self, A, B, M, solver):
        self.A, self.B, self.M = A.tocsc(), B.tocsr(), M.tocsr()
        self.symmetric = all(is_symmetric(X) for X in (self.A, self.B, self.M))
        self.lu = solver(self.A)
        self.BT, self.MT = (self.B, self.M) if self.symmetric else (self.B.T.tocsr(), self.M.T.tocsr())
        self.solve_T = getattr(self.lu, "solve_T", None) or (self.lu.solve if self.symmetric else None)
        if self.solve_T is None:
            raise ValueError(f"solver {type(self.lu).__name__} has no solve_T and the matrix is not "
                             "symmetric; use solver=pdeinv.fem.solvers.SuperLU")

    def flops(self) -> float:
        """One column's step: the solve, ``2·fill(LU)`` (``FILL_FALLBACK·nnz(A)`` for a solver that reports
        no fill, e.g. AMG-CG), and the products by ``B`` and ``M``, ``2·nnz`` each."""
        fill = getattr(self.lu, "fill", None)  # an optional attribute of the solver object
        return 2 * (fill if fill is not None else FILL_FALLBACK * self.A.nnz) + 2 * (self.B.nnz + self.M.nnz)

    def start(self, U, V=None):
        return (U,) if self.width == 1 else (U, np.zeros_like(U) if V is None else V)

    def start_T(self, s):
        return s[0]

    def field(self, s):
        return s[0]

    def inject(self, s, W):
        return (s[0] + W, *s[1:])

    def zeros(self, n: int, b: int):
        return tuple(np.zeros((n, b)) for _ in range(self.width))


class Theta(Implicit):
    """θ-scheme step for ``M u' + L u = 0`` (θ = 1 backward Euler, ½ Crank–Nicolson)."""

    width = 1

    def __init__(self, M, L, dt: float, theta: float, solver):
        self.dt, self.theta, self.n = float(dt), float(theta), M.shape[0]
        self.L = L.tocsr()  # kept for the modal form (:mod:`.modal`): the pencil L φ = μ M φ
        self._factor(M + theta * dt * L, M - (1.0 - theta) * dt * L, M, solver)

    def gain(self, mu):
        """Per-step factor ``r(dt μ) = (1 − (1−θ) dt μ) / (1 + θ dt μ)`` of a mode ``L φ = μ M φ``
        (symmetric ``L`` and ``M``: the step is diagonal in the M-orthonormal modes)."""
        z = self.dt * mu
        return (1.0 - (1.0 - self.theta) * z) / (1.0 + self.theta * z)

    def step(self, s):
        return (self.lu.solve(self.B @ s[0]),)

    def step_T(self, s):
        return (self.BT @ self.solve_T(s[0]),)


class Newmark(Implicit):
    """Newmark average-acceleration step on ``(u, v)`` for ``M u'' + c² K u = 0`` (module docstring).
    Time-reversible: the step with ``−dt`` undoes it; the state's companion of ``u`` is ``v``."""

    width = 2
    reversible = True

    def pack(self, U, C):
        return U, C

    def unpack(self, s):
        return s
    def __init__(self, M, K, c: float, dt: float, solver):
        self.dt, self.n = float(dt), M.shape[0]
        q = (c * dt / 2) ** 2
        self._factor(M + q * K, M - q * K, M, solver)

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
        W = self.solve_T(Ub + k * Vb)
        return self.BT @ W - k * Vb, self.dt * (self.MT @ W) - Vb


class Leapfrog:
    """Central-difference step on ``(uⱼ₋₁, uⱼ)`` with a lumped mass (module docstring).
    Time-reversible: ``uⱼ₋₂ = 2uⱼ₋₁ − uⱼ − q M_L⁻¹K uⱼ₋₁`` undoes a step exactly (in exact
    arithmetic; to rounding in floating point); the state's companion of ``uⱼ`` is ``uⱼ₋₁``."""

    width = 2
    reversible = True
    lu = None  # explicit: no factorization

    def pack(self, U, C):
        return C, U

    def unpack(self, s):
        return s[1], s[0]
    def __init__(self, minv: np.ndarray, K, c: float, dt: float):
        self.dt, self.n = float(dt), K.shape[0]
        self.qminv = (c * dt) ** 2 * np.asarray(minv, dtype=float)[:, None]  # q M_L⁻¹, folded once
        self.K = sp.csr_matrix(K)
        self.symmetric = is_symmetric(self.K)
        self.KT = self.K if self.symmetric else self.K.T.tocsr()

    def flops(self) -> float:
        """One column's step: the product by ``K``, ``2·nnz``."""
        return 2.0 * self.K.nnz

    def start(self, U):
        return U - 0.5 * (self.qminv * (self.K @ U)), U

    def start_T(self, s):
        return s[1] + s[0] - 0.5 * (self.KT @ (self.qminv * s[0]))

    def field(self, s):
        return s[1]

    def inject(self, s, W):
        return s[0], s[1] + W

    def zeros(self, n: int, b: int):
        return np.zeros((n, b)), np.zeros((n, b))

    def step(self, s, sign: float = 1.0):
        P, U = s
        if sign == 1.0:
            return U, 2.0 * U - P - self.qminv * (self.K @ U)
        return 2.0 * P - U - self.qminv * (self.K @ P), P

    def step_T(self, s):
        P, U = s
        return -U, P + 2.0 * U - self.KT @ (self.qminv * U)
