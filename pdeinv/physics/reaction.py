"""Nonlinear heat (Allen–Cahn reaction): ``M u' + κ K u + M f(u) = 0``, ``f(u) = r (u³ − u)``.

**Discretization.** Consistent P1/P2 mass ``M`` and stiffness ``K`` (scikit-fem, condensed), the
reaction projected nodally: ``M f(u)`` with ``f`` applied to the coefficients (the "group" or
nodal-interpolation form of the reaction; its Jacobian is simply ``M diag(f'(u))``). At ``r = 0``
this is exactly :class:`~pdeinv.physics.heat.Heat`'s scheme. θ-scheme (θ = 1 backward Euler,
θ = ½ Crank–Nicolson), one step ``u → w`` solves

    R(w; u) = A w + θ dt M f(w) − B u + (1−θ) dt M f(u) = 0,   A = M + θ dt κK,  B = M − (1−θ) dt κK,

with ``J(w) = A + θ dt M diag(f'(w))``, from the semi-implicit predictor ``w₀ = A⁻¹(B u − dt M f(u))``
(one multi-column solve with the factorization of ``A``). ``θ dt r ≥ 1`` is refused with the number
of steps that would do: since ``f' ≥ −r``, the step's Jacobian is ``(1 − θ dt r) M + θ dt κK`` plus a
non-negative reaction term, which may become singular (several solutions of one step) when
``θ dt r ≥ 1`` (exactly so with a lumped mass).

**The solver** (``solver="auto"``, the default): Newton where the blocks are tridiagonal after
reverse Cuthill–McKee (P1 in 1-D: LAPACK's ``gttrf`` makes a block LU cheaper than the chord's extra
iterations), the chord everywhere else.

**The chord solver** (``solver="chord"``). One frozen matrix ``A_c = A + θ dt c M``
(symmetric positive definite, as ``1 + θ dt c > 0``) carries every solve: the step by the chord
(modified Newton) iteration ``w ← w − A_c⁻¹ R(w)``, all columns at once as one multi-column solve;
the tangent ``J(w) δ = rhs`` and its transpose ``J(w)ᵀ z = rhs`` by Richardson iteration ``δ ← δ +
A_c⁻¹(rhs − J δ)`` from ``δ₀ = A_c⁻¹ rhs``. All three have the error map ``e ← −θ dt A_c⁻¹ M
diag(f'(ξ) − c) e``, contraction factor ``ρ ≤ θ dt · max|f' − c| · ‖A_c⁻¹ M‖ ≈ θ dt · max|f' − c| /
(1 + θ dt c)`` (``‖A_c⁻¹M‖_M = 1/(1 + θ dt (c + κλ₁))``). Over ``c ∈ [f'_min, f'_max]`` the bound
decreases up to the midpoint and increases after it (its derivative there has the sign of ``1 + θ dt
f'_min > 0``): ``c`` is the midpoint of ``f'`` over the batch's current values, ``ρ ≈ θ dt (f'_max −
f'_min)/2 / (1 + θ dt c)``, rounded to the grid ``−r + (r/2)ℤ`` so that a run factorizes a handful
of ``A_c`` (sparse LU of one ``N × N`` matrix each, cached); on allen_cahn_1d ``ρ ≈ 0.025``.
**Stopping, relative to rounding**: a column stops when its update ``‖δ_k‖∞ ≤
rtol·‖w‖∞`` (``rtol = 1e-14``, 45 ulp; the error left is ``≈ ρ·rtol``). **Fallback**: a column whose
measured contraction ``‖δ_k‖∞/‖δ_{k−1}‖∞`` exceeds ½, whose update is not finite, or which is not
done after 30 iterations, is solved by block-LU Newton (from the predictor; a tangent solve: by its
block LU) — large amplitudes at strong reactions (``f'_max ≈ 3 r max u²``, ``ρ → 1``).
``newton_iterations`` (per step: block-LU Newton iterations, 0 when the chord solved every column),
``chord_iterations`` (per step: the most any column needed) and ``fallback_columns`` (columns of
steps and tangent solves handed to the block LU) describe the last call.

**The Newton solver** (``solver="newton"``): Newton's method per step; each column of the batch has
its own Jacobian: one LU of the block-diagonal ``J`` of the columns not yet converged, per Newton
iteration (LAPACK's tridiagonal or band LU where the blocks' band is narrow, as in 1-D; else
``scipy.sparse.linalg.splu``). A column stops when its Newton update
``‖δ_k‖∞ ≤ rtol·‖w‖∞``, or when the quadratic model predicts the next error below that,
``‖δ_k‖³/‖δ_{k−1}‖² ≤ rtol·‖w‖∞`` (the update ``δ_k`` is then applied and nothing is factorized
again). The tangent solves factorize ``J`` once per step. Quadratic convergence, but a block LU
per iteration: on allen_cahn_1d (tridiagonal blocks) faster than the chord (1 024 rows: forward 1.4 s
against 2.2 s, vjp 4 s against 7 s), on allen_cahn_2d (SuperLU's blocks) 4–6× slower.

**Exact discrete adjoint.** The tangent of a step is ``δw = J(w)⁻¹ C(u) δu`` with
``C(u) = B − (1−θ) dt M diag(f'(u))``; its transpose ``ū = C(u)ᵀ J(w)⁻ᵀ w̄`` needs the states
``u`` and ``w`` of every step. They are recomputed from checkpoints: the forward run keeps every
``k``-th state (``k = ⌈√steps⌉`` by default), the reverse sweep recomputes one segment of ``k``
states at a time, so at most ``⌈steps/k⌉ + k + 1 ≈ 2√steps`` fields per column are held
(``peak_fields`` after each call). ``checkpoint_every=1`` stores the whole trajectory (the
reference the tests compare against). The adjoint solves ``J(w)ᵀ z = w̄`` at the converged state
(no nonlinear iteration), so ``vjp`` ≈ 2 forward runs (checkpoints, then segment recomputation) plus
one transposed tangent solve per step; after a forward run at bitwise the same ``X`` (the torch
bridge: forward, then backward) its checkpoints are reused, and ``vjp`` costs one run plus the
solves.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from scipy.linalg import lapack
from scipy.sparse.csgraph import reverse_cuthill_mckee

from .._checks import choice, count, nonnegative, positive
from ..errors import ConvergenceError
from .nonlinear import Physics

SCHEMES = {"be": 1.0, "cn": 0.5}
#: chord iterations per step in :meth:`ReactionHeat.forward_flops`' cost model (measured 10–12 per step
#: on allen_cahn_2d's prior draws at ``rtol = 1e-14``)
ITERATIONS = 11


class NewtonFailed(ConvergenceError):
    """Newton's method did not converge within ``max_newton`` iterations (a numerical failure: the
    training guard rejects the update that led there, :func:`pdeinv.methods.guard.apply_if_finite`)."""


def allen_cahn(r: float):
    """``f(u) = r (u³ − u)`` and ``f'(u) = r (3u² − 1)``."""
    return (lambda u: r * (u * u * u - u)), (lambda u: r * (3.0 * u * u - 1.0))


class _Blocks:
    """The block-diagonal Jacobians ``I_b ⊗ A + s (I_b ⊗ M) diag(vec D)`` of ``b`` columns, assembled
    straight into CSC arrays on the pattern of ``A + M``, each block in the reverse Cuthill–McKee order
    of that pattern and factorized without reordering (``permc_spec='NATURAL'``): the blocks stay
    banded, and the generic orderings spent most of the time ordering (1-D, 32 columns: 3 ms per
    factorization with MMD against under 1 ms)."""

    def __init__(self, A, M):
        pattern = (abs(A) + abs(M)).tocsr()
        self.perm = reverse_cuthill_mckee(pattern, symmetric_mode=True)
        P = pattern[self.perm][:, self.perm].tocsc()
        P.sort_indices()
        self.n, self.nnz, self.indptr, self.indices = P.shape[0], P.nnz, P.indptr, P.indices
        self.col = np.repeat(np.arange(self.n), np.diff(P.indptr))
        rows_orig, cols_orig = self.perm[self.indices], self.perm[self.col]
        self.a = np.asarray(A.tocsr()[rows_orig, cols_orig]).ravel()
        self.m = np.asarray(M.tocsr()[rows_orig, cols_orig]).ravel()
        self.band = int(np.abs(self.indices - self.col).max()) if self.nnz else 0
        self._struct, self._band = {}, {}
        if self.band == 1:  # the three diagonals of A and M in the banded order
            Ap, Mp = A.tocsr()[self.perm][:, self.perm], M.tocsr()[self.perm][:, self.perm]
            self.tri = [(Ap.diagonal(k), Mp.diagonal(k)) for k in (-1, 0, 1)]

    def _structure(self, b: int):
        if b not in self._struct:
            starts = (np.arange(b)[:, None] * self.nnz + self.indptr[None, :-1]).ravel()
            indptr = np.append(starts, b * self.nnz)
            indices = (self.indices[None, :] + self.n * np.arange(b)[:, None]).ravel()
            self._struct = {b: (indptr, indices)}  # the last size: the active set changes rarely
        return self._struct[b]

    def jacobian(self, scale, D):
        """LU of ``I ⊗ A + scale · (I ⊗ M) diag(vec D)``, ``D`` ``(N, b)`` (column-stacked)."""
        b = D.shape[1]
        if self.band == 1 <= BANDED_MAX:
            return _BandFactor.tridiagonal(self, scale, D[self.perm])
        data = (self.a[None, :] + scale * self.m[None, :] * D[self.perm].T[:, self.col]).ravel()
        if self.band <= BANDED_MAX:
            return _BandFactor(self, b, data)
        indptr, indices = self._structure(b)
        J = sp.csc_matrix((data, indices, indptr), shape=(self.n * b, self.n * b))
        return _Factor(sla.splu(J, permc_spec="NATURAL"), self.perm, self.n)

    def band_positions(self, b: int) -> np.ndarray:
        """Where the entries of :meth:`jacobian`'s ``data`` go in LAPACK's band storage (flat, cached
        for the last ``b``): row ``2k + i − j`` of column ``j``."""
        if b not in self._band:
            offset = self.n * np.repeat(np.arange(b), self.nnz)
            rows, cols = np.tile(self.indices, b) + offset, np.tile(self.col, b) + offset
            self._band = {b: (2 * self.band + rows - cols) * (self.n * b) + cols}
        return self._band[b]

    def bytes(self, b: int) -> int:
        """The memory of one :meth:`jacobian` of ``b`` columns (factors, float64), about."""
        per = (3 * self.band + 1) if self.band <= BANDED_MAX else 2 * (self.band + 1)
        return 8 * self.n * b * per


#: the widest block band (after reverse Cuthill–McKee) factorized by LAPACK's banded LU (``gbtrf``):
#: P1 and P2 in 1-D; SuperLU's general factorization of the block-diagonal matrix cost 85 ms for the
#: 1 024 tridiagonal 63-blocks of allen_cahn_1d, dominated by its per-column overhead
BANDED_MAX = 8


#: the most memory :meth:`ReactionHeat.linearize` spends on exact per-step factorizations (allen_cahn_1d,
#: 1 024 rows, 100 steps: 0.2 GB); a Gauss–Newton solve with them took 5 s against 32 s by the chord's
#: tangent, the same to 3e-13
KEPT_FACTORS_BYTES = 2**30


class _BandFactor:
    """LAPACK's tridiagonal (``gttrf``, band 1) or banded (``gbtrf``) LU, with partial pivoting, of the
    block-diagonal Jacobian, the blocks in their banded order (:class:`_Blocks`); solved on
    column-stacked vectors in the original order."""

    def __init__(self, blocks, b, data):
        k, n = blocks.band, blocks.n
        self.k, self.perm, self.n = k, blocks.perm, n
        ab = np.zeros((3 * k + 1, n * b))
        ab.ravel()[blocks.band_positions(b)] = data
        self._factor(lapack.dgbtrf(ab, k, k))

    def _factor(self, out):
        *self.lu, info = out
        if info > 0:
            raise np.linalg.LinAlgError(f"the step's Jacobian is singular (pivot {info})")

    @classmethod
    def tridiagonal(cls, blocks, scale, Dp):
        """Band 1: the diagonals ``a_k + scale · m_k · D`` straight from ``D`` ``(n, b)`` in the banded order
        (column ``j`` of ``M diag(D)`` scaled by ``D_j``), then ``gttrf`` (3-5× faster than ``gbtrf``)."""
        self = cls.__new__(cls)
        n, b = Dp.shape
        self.k, self.perm, self.n = 1, blocks.perm, n
        (al, ml), (a0, m0), (au, mu) = blocks.tri
        lower, upper = np.zeros((b, n)), np.zeros((b, n))
        lower[:, :-1] = (al[:, None] + scale * ml[:, None] * Dp[:-1]).T  # J[i+1, i]: scaled by D_i
        upper[:, 1:] = (au[:, None] + scale * mu[:, None] * Dp[1:]).T  # J[i, i+1]: scaled by D_{i+1}
        diag = (a0[:, None] + scale * m0[:, None] * Dp).T
        self._factor(lapack.dgttrf(lower.ravel()[:-1], diag.ravel(), upper.ravel()[1:]))
        return self

    def _solve(self, rhs, trans):
        if self.k == 1:
            return lapack.dgttrs(*self.lu, rhs, trans=trans)
        lu, piv = self.lu
        return lapack.dgbtrs(lu, self.k, self.k, rhs, piv, trans=0 if trans == "N" else 1)

    def solve(self, v, trans: str = "N"):
        V = v.reshape(-1, self.n)
        x, info = self._solve(np.ascontiguousarray(V[:, self.perm]).ravel(), trans)
        out = np.empty_like(V)
        out[:, self.perm] = x.reshape(V.shape)
        return out.ravel()

    def solve_many(self, V, trans: str = "N"):
        """The solve of ``k`` right-hand sides per block, ``V`` ``(b, n, k)`` -> ``(b, n, k)``."""
        b, n, k = V.shape
        x, info = self._solve(np.asfortranarray(V[:, self.perm].reshape(b * n, k)), trans)
        out = np.empty_like(V)
        out[:, self.perm] = x.reshape(b, n, k)
        return out


class _Factor:
    """A block factorization in the blocks' order, solved on column-stacked vectors in the original."""

    def __init__(self, lu, perm, n):
        self.lu, self.perm, self.n = lu, perm, n

    def solve(self, v, trans: str = "N"):
        V = v.reshape(-1, self.n)
        out = np.empty_like(V)
        out[:, self.perm] = self.lu.solve(np.ascontiguousarray(V[:, self.perm]).ravel(),
                                          trans=trans).reshape(V.shape)
        return out.ravel()

    def solve_many(self, V, trans: str = "N"):
        b, n, k = V.shape
        out = np.empty_like(V)
        out[:, self.perm] = self.lu.solve(np.asfortranarray(V[:, self.perm].reshape(b * n, k)),
                                          trans=trans).reshape(b, n, k)
        return out


def _vec(U):
    return np.ascontiguousarray(U.T).ravel()


def _unvec(u, n):
    return u.reshape(-1, n).T


_TINY = np.finfo(float).tiny


def _contract(update, X, rtol: float, max_iterations: int, max_ratio: float, history=None):
    """The fixed-point iteration ``X[:, a] += update(X[:, a], a)`` on the columns ``a`` not yet done,
    in place. A column is done when its update ``‖δ_k‖∞ ≤ rtol·‖x‖∞`` (the error left is then about
    ``q·rtol·‖x‖∞``; stopping on the predicted error ``q/(1−q)·‖δ_k‖∞`` instead would leave chord and
    Newton tangents 1e-12 apart); it *fails* when the measured
    contraction ``q_k = ‖δ_k‖∞/‖δ_{k−1}‖∞ > max_ratio``, its update is not finite, or it is not done
    after ``max_iterations``. Returns (iterations, failed column indices)."""
    active, prev, failed, its = np.arange(X.shape[1]), np.full(X.shape[1], np.inf), [], 0
    while active.size and its < max_iterations:
        every = active.size == X.shape[1]  # then views, no copies
        Xa = X if every else X[:, active]
        delta = update(Xa, slice(None) if every else active)
        Xa += delta
        if Xa is not X:
            X[:, active] = Xa
        its += 1
        size = np.abs(delta).max(axis=0)
        scale = rtol * np.maximum(np.abs(Xa).max(axis=0), _TINY)
        if history is not None:
            history.append(float((size / (scale / rtol)).max()))
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(np.isfinite(prev[active]), size / prev[active], np.nan)
        done = size <= scale
        bad = ~done & ((q > max_ratio) | ~np.isfinite(size))
        prev[active] = size
        failed.append(active[bad])
        active = active[~done & ~bad]
    return its, np.concatenate([*failed, active])


def _newton(op, U, FU, W, history=None):
    """Newton's method for ``R(w; u) = 0`` from ``W`` (in place), one block-LU of the Jacobians of the
    columns not yet converged per iteration; returns ``(W, iterations)``."""
    n, dt, th = op.n_in, op.dt, op.theta
    G = op.B @ U - (1.0 - th) * dt * (op.M @ FU)
    active = np.arange(U.shape[1])
    prev = np.full(U.shape[1], np.inf)
    its = 0
    while active.size:
        if its == op.max_newton:
            raise NewtonFailed(f"Newton did not converge in {op.max_newton} iterations (dt={dt:.3g}, "
                               f"strength={op.strength:g}); use more steps")
        Wa = W[:, active]
        Rb = op.A @ Wa + th * dt * (op.M @ op.f(Wa)) - G[:, active]
        lu = op.blocks.jacobian(th * dt, op.df(Wa))
        delta = -_unvec(lu.solve(_vec(Rb)), n)
        W[:, active] = Wa + delta
        its += 1
        size = np.abs(delta).max(axis=0)
        scale = op.rtol * np.maximum(np.abs(W[:, active]).max(axis=0), _TINY)
        if history is not None:
            history.append(float((size / (scale / op.rtol)).max()))
        quadratic = np.isfinite(prev[active]) & (size**3 <= scale * prev[active] ** 2)
        done = (size <= scale) | quadratic
        prev[active] = size
        active = active[~done]
    return W, its


class _BlockTangent:
    """``J(w)⁻¹`` (or ``J(w)⁻ᵀ``) of every column by its block LU, on ``(N, b)`` columns."""

    def __init__(self, op, D):
        self.lu, self.n = op.blocks.jacobian(op.theta * op.dt, D), op.n_in

    def solve(self, Rhs, trans: str = "N"):
        return _unvec(self.lu.solve(_vec(Rhs), trans=trans), self.n)

    def solve_many(self, Z, trans: str = "N"):
        """The solve of ``k`` right-hand sides per column, ``Z`` ``(N, b, k)`` -> ``(N, b, k)``."""
        return self.lu.solve_many(Z.transpose(1, 0, 2), trans).transpose(1, 0, 2)


class Newton:
    """Block-LU Newton per step, one block LU per step for the tangent (quadratic convergence; the
    reference the chord solver is tested against)."""

    name = "newton"

    def step(self, op, U, FU, W, history=None):
        W, its = _newton(op, U, FU, W, history)
        op.newton_iterations.append(its)
        op.chord_iterations.append(0)
        return W

    def tangent(self, op, W):
        return _BlockTangent(op, op.df(W))


class _FrozenTangent:
    """``J(w) x = rhs`` (``trans='T'``: ``J(w)ᵀ z = rhs``) by Richardson iteration preconditioned with
    the frozen ``A_c``: ``x ← x + A_c⁻¹(rhs − J x)`` from ``x₀ = A_c⁻¹ rhs``; columns that do not
    contract are solved by their block LU."""

    def __init__(self, op, chord, W):
        self.op, self.chord, self.D = op, chord, op.df(W)
        self.lu = op.frozen(self.D)

    def _apply(self, X, a, trans):
        op, s = self.op, self.op.theta * self.op.dt
        if trans == "N":
            return op.A @ X + s * (op.M @ (self.D[:, a] * X))
        return op.A @ X + s * (self.D[:, a] * (op.M @ X))  # A, M symmetric

    def solve(self, Rhs, trans: str = "N"):
        op, lu, chord = self.op, self.lu, self.chord
        # A_c is symmetric (so is A_c⁻ᵀ = A_c⁻¹): SuperLU's transposed solve took three times as long
        X = np.ascontiguousarray(lu.solve(np.asarray(Rhs, float)))
        _, failed = _contract(lambda Xa, a: lu.solve(Rhs[:, a] - self._apply(Xa, a, trans)),
                              X, op.rtol, chord.max_iterations, chord.max_ratio)
        if failed.size:
            op.fallback_columns += failed.size
            X[:, failed] = _BlockTangent(op, self.D[:, failed]).solve(Rhs[:, failed], trans)
        return X


class Chord(Newton):
    """The chord (modified Newton) iteration with the frozen ``A_c = A + θ dt c M`` of the whole batch
    (module docstring); columns whose updates do not contract by ``max_ratio`` per iteration, or are
    not done after ``max_iterations``, fall back to :class:`Newton` from the predictor."""

    name = "chord"

    def __init__(self, max_iterations: int = 30, max_ratio: float = 0.5):
        self.max_iterations, self.max_ratio = count(max_iterations, "max_iterations"), max_ratio

    def step(self, op, U, FU, W, history=None):
        th, dt = op.theta, op.dt
        W = np.ascontiguousarray(W)  # the solves return Fortran order: matvecs would copy each time
        W0 = W.copy()
        G = op.B @ U - (1.0 - th) * dt * (op.M @ FU)
        lu = op.frozen(op.df(W))
        its, failed = _contract(
            lambda Wa, a: -lu.solve(op.A @ Wa + th * dt * (op.M @ op.f(Wa)) - G[:, a]),
            W, op.rtol, self.max_iterations, self.max_ratio, history)
        newton_its = 0
        if failed.size:
            op.fallback_columns += failed.size
            W[:, failed], newton_its = _newton(op, U[:, failed], FU[:, failed], W0[:, failed])
        op.chord_iterations.append(its)
        op.newton_iterations.append(newton_its)
        return W

    def tangent(self, op, W):
        return _FrozenTangent(op, self, W)


SOLVERS = {"chord": Chord, "newton": Newton}


#: a run marches blocks of at most this many field entries (128 kB; at least :data:`BLOCK_COLUMNS`
#: columns, the numpy and SuperLU calls' overhead): 8 192 allen_cahn_1d draws took 32 s at once, 17 s in
#: blocks of 256 columns, 26 s in blocks of 64
BLOCK_ENTRIES, BLOCK_COLUMNS = 2**14, 64


class ReactionHeat(Physics):
    """Final field of ``M u' + κ K u + M f(u) = 0`` after ``steps`` θ-steps (module docstring).
    ``strength`` is ``r`` in ``f(u) = r (u³ − u)``; ``checkpoint_every``: ``k`` (default ``⌈√steps⌉``;
    1 stores everything); ``solver``: ``"auto"`` (Newton on tridiagonal blocks, else the chord),
    ``"chord"`` (one frozen ``A_c``, Newton fallback), ``"newton"`` (block LU per iteration), or a
    strategy object with ``step(op, U, FU, W, history)`` and
    ``tangent(op, W).solve(rhs, trans)`` (:class:`Chord`, :class:`Newton`)."""

    linear = False
    output_space = "field"
    _last = None  # (X, kept states) of the last forward run

    def __init__(self, M, K, kappa=0.01, T=1.0, steps=100, strength=1.0, scheme="be",
                 checkpoint_every=None, rtol=1e-14, max_newton=100, solver="auto"):
        self.M, self.K = sp.csr_matrix(M), sp.csr_matrix(K)
        self.mass = self.M
        self.kappa = positive(kappa, "kappa")
        self.t_end = positive(T, "T")
        self.steps = count(steps, "steps")
        self.strength = nonnegative(strength, "strength")
        self.scheme_name = choice(scheme, "scheme", tuple(SCHEMES))
        self.theta = SCHEMES[scheme]
        self.dt = self.t_end / self.steps
        if self.theta * self.dt * self.strength >= 1.0:
            need = math.floor(self.theta * self.t_end * self.strength) + 1
            raise ValueError(f"θ·dt·strength = {self.theta * self.dt * self.strength:.3g} >= 1: a Newton "
                             f"step may have several solutions; allowed: steps >= {need} "
                             f"for T={self.t_end:g}, strength={self.strength:g}")
        self.k = count(checkpoint_every, "checkpoint_every") if checkpoint_every else math.ceil(
            math.sqrt(self.steps))
        self.rtol, self.max_newton = positive(rtol, "rtol"), count(max_newton, "max_newton")
        self.f, self.df = allen_cahn(self.strength)
        self.n_in = self.n_out = self.M.shape[0]
        dt, th = self.dt, self.theta
        self.A = (self.M + th * dt * self.kappa * self.K).tocsc()
        self.B = (self.M - (1.0 - th) * dt * self.kappa * self.K).tocsr()
        self.A_lu = sla.splu(self.A)
        self.blocks = _Blocks(self.A, self.M)
        if isinstance(solver, str) and choice(solver, "solver", ("auto", *SOLVERS)) == "auto":
            solver = "newton" if self.blocks.band == 1 <= BANDED_MAX else "chord"
        self.solver = SOLVERS[solver]() if isinstance(solver, str) else solver
        self._frozen: dict[int, object] = {}
        self.newton_iterations: list[int] = []  # per step of the last run: block-LU Newton iterations
        self.chord_iterations: list[int] = []  # per step of the last run: chord iterations
        self.fallback_columns = 0  # columns (of steps and tangent solves) the chord handed to Newton
        self.peak_fields = 0

    def forward_flops(self) -> float:
        """One column's forward, by a cost model: ``steps · (1 + ITERATIONS) · (2·fill(A) + 2·(nnz A +
        nnz M))``, the predictor's solve and :data:`ITERATIONS` chord iterations per step, each a residual
        and a solve with ``A``'s fill (Newton's fewer iterations each factorize: counted alike)."""
        fill = self.A_lu.L.nnz + self.A_lu.U.nnz
        return self.steps * (1 + ITERATIONS) * (2.0 * fill + 2.0 * (self.A.nnz + self.M.nnz))

    # -- one step ---------------------------------------------------------------------------------
    def step(self, U, history: list | None = None, guess=None):
        """``w`` with ``R(w; u) = 0`` for every column of ``U`` ``(N, b)`` (by ``self.solver``, module
        docstring). ``history``: a list that receives ``max_b ‖δ_k‖∞ / ‖w‖∞`` per iteration; ``guess``:
        the initial iterate (default: the semi-implicit predictor)."""
        FU = self.f(U)
        W = self.A_lu.solve(self.B @ U - self.dt * (self.M @ FU)) if guess is None else np.array(guess, float)
        return self.solver.step(self, U, FU, W, history)

    def frozen(self, D):
        """The LU of ``A_c = A + θ dt c M`` with ``c`` the midpoint of the values ``D`` of ``f'``,
        rounded to the grid ``−r + (r/2)ℤ`` (cached per grid point: a run factorizes a handful)."""
        r = self.strength
        key = 0 if r == 0 else int(np.rint((D.min() + D.max() + 2.0 * r) / r))
        if key not in self._frozen:
            if len(self._frozen) >= 64:
                self._frozen.clear()
            c = -r + 0.5 * r * key
            self._frozen[key] = sla.splu((self.A + self.theta * self.dt * c * self.M).tocsc())
        return self._frozen[key]

    def _C(self, U, V):
        """``C(u) v = B v − (1−θ) dt M (f'(u) ∘ v)``."""
        out = self.B @ V
        if self.theta < 1.0:
            out -= (1.0 - self.theta) * self.dt * (self.M @ (self.df(U) * V))
        return out

    def _C_T(self, U, Z):
        """``C(u)ᵀ z = Bᵀ z − (1−θ) dt f'(u) ∘ (Mᵀ z)`` (``B``, ``M`` symmetric)."""
        out = self.B @ Z
        if self.theta < 1.0:
            out -= (1.0 - self.theta) * self.dt * (self.df(U) * (self.M @ Z))
        return out

    def _reset_counts(self):
        self.newton_iterations, self.chord_iterations, self.fallback_columns = [], [], 0

    # -- the run ------------------------------------------------------------------------------------
    def _forward(self, X):
        kept, U = self._run_keeping(X)
        self._last = (X.copy(), kept)  # reused by a vjp at bitwise the same X (the bridge's backward)
        self.peak_fields = len(kept) + 1
        return np.ascontiguousarray(U.T)

    def _jvp(self, X, V):
        U, Vc = np.ascontiguousarray(X.T), np.ascontiguousarray(V.T)
        self._reset_counts()
        for _ in range(self.steps):
            W = self.step(U)
            Vc = self.solver.tangent(self, W).solve(self._C(U, Vc))
            U = W
        return np.ascontiguousarray(Vc.T)

    def _run_keeping(self, X):
        """The run from the rows of ``X``: ``(kept states, u_T)``, marched in blocks of columns that stay
        in cache (:data:`BLOCK_ENTRIES`); the per-step counts are the most any block needed."""
        self._reset_counts()
        w = max(BLOCK_COLUMNS, BLOCK_ENTRIES // self.n_in)
        parts, chord, newton = [], [], []
        for i in range(0, X.shape[0], w):
            self.chord_iterations, self.newton_iterations = [], []
            U, kept = np.ascontiguousarray(X[i:i + w].T), {}
            for j in range(self.steps):
                if j % self.k == 0:
                    kept[j] = U
                U = self.step(U)
            parts.append((kept, U))
            chord.append(self.chord_iterations)
            newton.append(self.newton_iterations)
        self.chord_iterations = [max(c) for c in zip(*chord, strict=True)]
        self.newton_iterations = [max(c) for c in zip(*newton, strict=True)]
        if len(parts) == 1:
            return parts[0]
        kept = {j: np.concatenate([p[0][j] for p in parts], axis=1) for j in parts[0][0]}
        return kept, np.concatenate([p[1] for p in parts], axis=1)

    def checkpoints(self, X):
        """The states ``u_j`` for ``j = 0, k, 2k, … < steps`` (``(N, B)`` each) of the run from ``X``:
        those of the last forward run if ``X`` is bitwise its input (a forward then a vjp at the same
        point, as the torch bridge does, pays the run once), else recomputed."""
        last = self._last
        if last is not None and last[0].shape == X.shape and np.array_equal(last[0], X):
            return last[1]
        return self._run_keeping(X)[0]

    def _vjp(self, X, R):
        self._reset_counts()
        kept = self.checkpoints(X)
        Ub = np.ascontiguousarray(R.T)
        peak = len(kept)
        for s in sorted(kept, reverse=True):
            e = min(s + self.k, self.steps)
            seg = [kept[s]]
            for _ in range(s, e):
                seg.append(self.step(seg[-1]))
            peak = max(peak, len(kept) + len(seg) - 1)
            for j in range(e, s, -1):  # transpose of step j: u_{j-1} -> u_j
                Z = self.solver.tangent(self, seg[j - s]).solve(Ub, "T")
                Ub = self._C_T(seg[j - s - 1], Z)
            del seg
        self.peak_fields = peak
        return np.ascontiguousarray(Ub.T)

    def linearize(self, X) -> tuple[np.ndarray, Tangent]:
        """``(P(X), P'(X))`` with the tangent kept for many products (a local inverse's CG): the whole
        trajectory and every step's tangent solver are stored, O(steps) fields (chord: ``f'(w)`` of
        each step and the shared ``A_c`` factors; Newton: a block LU per step) — memory traded for
        products at the cost of one tangent solve per step and no nonlinear iteration. Where every
        step's exact block factorization fits in :data:`KEPT_FACTORS_BYTES`, those are kept instead of
        the solver's tangent (a chord's Richardson iterations would be repeated in every product)."""
        U, states, lus = np.ascontiguousarray(np.atleast_2d(X).T), [], []
        self._reset_counts()
        exact = self.steps * self.blocks.bytes(U.shape[1]) <= KEPT_FACTORS_BYTES
        for _ in range(self.steps):
            W = self.step(U)
            states.append(U)
            lus.append(_BlockTangent(self, self.df(W)) if exact else self.solver.tangent(self, W))
            U = W
        return np.ascontiguousarray(U.T), Tangent(self, states, lus)

    @property
    def linearize_rows(self) -> int | None:
        """The most rows whose exact per-step factorizations fit in :data:`KEPT_FACTORS_BYTES` (the
        tangent :meth:`linearize` keeps for them costs one solve per step and product, the chord's ~10
        Richardson solves), or None where fewer than :data:`BLOCK_COLUMNS` rows fit (the chord's tangent
        serves any number). allen_cahn_2d at 16²: 372 rows; a Gauss–Newton step of 1 024 rows 54 s by the
        chord's tangent, 25 s in chunks of exact factors (each chunk's CG stops on its own rows)."""
        rows = KEPT_FACTORS_BYTES // max(self.steps * self.blocks.bytes(1), 1)
        return int(rows) if rows >= BLOCK_COLUMNS else None

    def jacobian(self, X) -> np.ndarray:
        """The Jacobians ``P'(x_b)`` of the rows of ``X`` ``(B, N)``, ``(B, N, N)``: the reverse sweep of
        :meth:`linearize`'s tangent on all ``N`` unit cotangents of each row at once, through every step's
        exact block LU (one multi-right-hand-side solve per step; no nonlinear iteration, no run per
        cotangent)."""
        _, tangent = self.linearize(X)
        return tangent.jacobian()

    def jacobian_bytes(self, B: int) -> int:
        """The memory of :meth:`jacobian` on ``B`` rows, about: three ``(B, N, N)`` float64 arrays."""
        return 3 * 8 * B * self.n_in * self.n_out

    def __repr__(self):
        return (f"ReactionHeat(N={self.n_in}, kappa={self.kappa}, T={self.t_end}, steps={self.steps}, "
                f"strength={self.strength}, scheme={self.scheme_name!r}, checkpoint_every={self.k})")


class Tangent:
    """``P'(X)`` of a :class:`ReactionHeat` run at fixed ``X`` (:meth:`ReactionHeat.linearize`):
    ``jvp(V)``, ``vjp(R)`` on ``(B, N)`` rows, the same products as ``op.jvp(X, ·)``/``op.vjp(X, ·)``."""

    def __init__(self, op: ReactionHeat, states: list, lus: list):
        self.op, self.states, self.lus = op, states, lus

    def jvp(self, V):
        op, Vc = self.op, np.ascontiguousarray(V.T)
        for U, lu in zip(self.states, self.lus, strict=True):
            Vc = lu.solve(op._C(U, Vc))
        return np.ascontiguousarray(Vc.T)

    def vjp(self, R):
        op, Ub = self.op, np.ascontiguousarray(R.T)
        for U, lu in zip(reversed(self.states), reversed(self.lus), strict=True):
            Ub = op._C_T(U, lu.solve(Ub, "T"))
        return np.ascontiguousarray(Ub.T)

    def jacobian(self) -> np.ndarray:
        """``P'(x_b)`` of every column ``b``, ``(B, N, N)``: :meth:`vjp` on the ``N`` unit cotangents of each
        column, ``Z ← C(u)ᵀ J(w)⁻ᵀ Z`` with ``Z`` ``(N, B, N)``, by each step's exact block LU (the chord's
        tangent is factorized here where :meth:`ReactionHeat.linearize` did not keep the factors)."""
        op = self.op
        n, B = op.n_in, self.states[0].shape[1]
        Z = np.ascontiguousarray(np.broadcast_to(np.eye(n)[:, None, :], (n, B, n)))
        for U, lu in zip(reversed(self.states), reversed(self.lus), strict=True):
            exact = lu if isinstance(lu, _BlockTangent) else _BlockTangent(op, lu.D)
            Z = exact.solve_many(Z, "T")
            CZ = op.B @ Z.reshape(n, B * n)  # C(u)ᵀ z
            if op.theta < 1.0:
                CZ -= (1.0 - op.theta) * op.dt * (op.df(U)[:, :, None] * (op.M @ Z.reshape(n, B * n))
                                                  .reshape(n, B, n)).reshape(n, B * n)
            Z = CZ.reshape(n, B, n)
        return np.ascontiguousarray(Z.transpose(1, 2, 0))
