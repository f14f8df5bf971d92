"""Nonlinear wave (sine-Gordon): ``M_L u'' + c² K u + M_L g(u) = 0``, ``g(u) = s·sin u``, ``v(0) = 0``.

**Scheme.** Störmer–Verlet (velocity form of the leapfrog) with the lumped (diagonal) mass
``M_L``, so the acceleration ``a(u) = c² M_L⁻¹ K u + g(u)`` costs one sparse product:

    v½ = v − (dt/2) a(u);   u' = u + dt v½;   v' = v½ − (dt/2) a(u').

From ``v₀ = 0`` its displacements are those of :class:`~pdeinv.physics.leapfrog.Leapfrog` (whose
fictitious ``u₋₁ = u₀ − ½(c dt)² M_L⁻¹K u₀`` is the same start): at ``s = 0`` this reproduces the
linear leapfrog scene to rounding. Explicit and symplectic; stable while ``dt² (c² λ_max + s) < 4``
(``λ_max`` of ``Kφ = λ M_L φ``; ``|g'| ≤ s``): ``steps=None`` picks the fewest steps with
``dt ≤ cfl · dt_max`` (``cfl = 0.5``), a given ``steps`` above the limit is refused.

**Reversible.** The same step with ``−dt`` undoes it (to rounding): :meth:`reverse` maps
``(u_T, v_T)`` back to ``(u₀, v₀)`` — an exact nonlinear inverse of the full final state, and the
local inverse SIP uses (:class:`pdeinv.inverse.TimeReversal`, with ``v_T`` borrowed from the
forward run of the current guess).

**Exact discrete adjoint, no stored trajectory.** With ``A(u) = c² M_L⁻¹ K + diag(g'(u))`` the
transposed step maps ``(ū', v̄')`` to

    ū' ← ū' − (dt/2) A(u')ᵀ v̄';   v̄½ = v̄' + dt ū';   ū = ū';   v̄ = v̄½;   ū ← ū − (dt/2) A(u)ᵀ v̄½,

which needs the states ``u`` and ``u'`` of each step: the reverse sweep recomputes them by
stepping backwards from the final state alongside (``recompute='reverse'``, O(1) fields; the final state
of the last forward run if the vjp is at bitwise its input, as the torch bridge's backward is), or
reads a stored trajectory (``recompute='store'``, the reference in the tests). The reversed states
differ from the forward ones by rounding (measured below 1e-14 relative at the defaults), which is
the only difference between the two.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import torch

from .._checks import batch, choice, count, nonnegative, positive
from .backends.modes import largest_eigenvalue
from .nonlinear import Physics


def _scaled(f, U, s: float) -> np.ndarray:
    """``s·f(U)`` with ``f`` torch's vectorized ``torch.sin``/``torch.cos`` (within an ulp of numpy's and
    3–5× faster on one thread: 22 against 71 ms on 16 129 × 256 values), read from the array's memory."""
    U = np.ascontiguousarray(U)
    out = f(torch.from_numpy(U if U.flags.writeable else U.copy())).numpy()  # torch warns on read-only
    out *= s
    return out


#: entries of one ``(N, b)`` block of fields that :meth:`SineGordon._by_columns` marches at a time (4 MB)
BLOCK_ENTRIES = 2**19


class SineGordon(Physics):
    """Displacement at ``T`` of ``M_L u'' + c² K u + M_L s sin u = 0`` from ``(u₀, 0)`` (module
    docstring). ``M_lumped``: the lumped mass on the free unknowns (diagonal, positive)."""

    linear = False
    output_space = "field"
    reversible = True  # Störmer–Verlet: final_state and reverse run the full state both ways
    _last = None  # (X, u_T, v_T) of the last forward run

    def __init__(self, M_lumped, K, c=1.0, T=1.0, steps=None, strength=1.0, cfl=0.5, recompute="reverse"):
        m = np.asarray(sp.csr_matrix(M_lumped).diagonal(), dtype=float)
        off = sp.csr_matrix(M_lumped) - sp.diags(m)
        if (off.nnz and abs(off).max() > 0) or not np.all(m > 0):
            raise ValueError("SineGordon needs a lumped mass: a diagonal matrix with positive entries")
        self.mass = sp.diags(m).tocsr()
        self.K = sp.csr_matrix(K)
        self.c = positive(c, "c")
        self.t_end = positive(T, "T")
        self.strength = nonnegative(strength, "strength")
        self.recompute = choice(recompute, "recompute", ("reverse", "store"))
        self.lam_max = largest_eigenvalue(self.mass, self.K)
        self.dt_max = 2.0 / math.sqrt(self.c**2 * self.lam_max + self.strength)
        if steps is None:
            cfl = positive(cfl, "cfl")
            if cfl >= 1:
                raise ValueError(f"cfl={cfl!r} is not allowed; expected 0 < cfl < 1 (dt = cfl·dt_max)")
            steps = math.ceil(self.t_end / (cfl * self.dt_max))
        self.steps = count(steps, "steps")
        self.dt = self.t_end / self.steps
        if self.dt >= self.dt_max:
            need = math.floor(self.t_end / self.dt_max) + 1
            raise ValueError(f"dt = T/steps = {self.dt:.4g} is at or above the stability limit "
                             f"2/√(c²λ_max + s) = {self.dt_max:.4g}; allowed: steps >= {need}, or steps=None")
        self.qminv = self.c**2 / m[:, None]  # c² M_L⁻¹, folded once
        self.n_in = self.n_out = len(m)

    # -- the scheme --------------------------------------------------------------------------------
    def accel(self, U):
        """``a(u) = c² M_L⁻¹ K u + s sin u`` on ``(N, b)`` columns."""
        a = self.K @ U
        a *= self.qminv
        a += _scaled(torch.sin, U, self.strength)
        return a

    def _A_T(self, U, W):
        """``A(u)ᵀ w = c² Kᵀ M_L⁻¹ w + s cos(u) ∘ w`` (``K`` symmetric)."""
        out = self.K @ (self.qminv * W)
        out += _scaled(torch.cos, U, self.strength) * W
        return out

    def _A(self, U, W):
        out = self.K @ W
        out *= self.qminv
        out += _scaled(torch.cos, U, self.strength) * W
        return out

    def step(self, U, V, sign: float = 1.0, a=None):
        """One Störmer–Verlet step on ``(N, b)`` columns; ``sign=-1`` undoes a step. ``a``: ``a(U)`` if
        known. Returns ``(U', V', a(U'))``: the next step starts with the acceleration this one ended
        with (one sparse product per step, bitwise the same as computing it twice)."""
        h = sign * self.dt
        Vh = V - 0.5 * h * (self.accel(U) if a is None else a)
        U1 = U + h * Vh
        a1 = self.accel(U1)
        return U1, Vh - 0.5 * h * a1, a1

    def forward_flops(self) -> float:
        """One column's forward, by a cost model: ``steps · (2·nnz K + 10 N)`` (the product by ``K``, the
        sine and the updates of an explicit step)."""
        return self.steps * (2.0 * self.K.nnz + 10.0 * self.n_in)

    def _march(self, U, V, sign: float = 1.0, keep: list | None = None):
        if keep is None:
            return self._by_columns(lambda u, v: self._march_block(u, v, sign), U, V)
        return self._march_block(U, V, sign, keep)

    def _march_block(self, U, V, sign: float = 1.0, keep: list | None = None):
        a = None
        for _ in range(self.steps):
            U, V, a = self.step(U, V, sign, a)
            if keep is not None:
                keep.append(U)
        return U, V

    def _by_columns(self, f, *arrays):
        """``f`` on blocks of at most :data:`BLOCK_ENTRIES` ``/ N`` columns of the ``(N, b)`` ``arrays``
        (contiguous copies), the results joined: a block's fields stay in cache for the whole run (the march
        is bound by memory traffic: at 16 129 unknowns, 256 columns at once took 1.5× as long as blocks
        of 32)."""
        b, w = arrays[0].shape[1], max(1, BLOCK_ENTRIES // max(self.n_in, 1))
        if b <= w:
            return f(*arrays)
        parts = [f(*(np.ascontiguousarray(a[:, i:i + w]) for a in arrays)) for i in range(0, b, w)]
        return tuple(np.concatenate(p, axis=1) for p in zip(*parts, strict=True))

    def _pair(self, U, V, names):
        U, single = batch(U, self.n_in, names[0])
        V = np.zeros_like(U) if V is None else batch(V, self.n_in, names[1])[0]
        if V.shape != U.shape:
            raise ValueError(f"{names[1]} has shape {V.shape}; expected the shape of {names[0]} {U.shape}")
        return np.ascontiguousarray(U.T), np.ascontiguousarray(V.T), single

    def final_state(self, U0, V0=None) -> tuple[np.ndarray, np.ndarray]:
        """``(u_T, v_T)`` from ``(u₀, v₀)`` (``v₀ = 0`` if omitted: then the last forward run's, if ``U0`` is
        bitwise its input — SIP's time reversal after its forward), batch-first."""
        U, V, single = self._pair(U0, V0, ("U0", "V0"))
        end = self._march(U, V) if V0 is not None else self._final(U)
        out = tuple(np.array(a.T, order="C") for a in end)  # copies: never a view of the kept run
        return tuple(a[0] for a in out) if single else out

    def reverse(self, UT, VT) -> tuple[np.ndarray, np.ndarray]:
        """Step back from ``(u_T, v_T)`` to ``(u₀, v₀)``: the scheme with ``−dt``."""
        U, V, single = self._pair(UT, VT, ("UT", "VT"))
        out = tuple(np.ascontiguousarray(a.T) for a in self._march(U, V, -1.0))
        return tuple(a[0] for a in out) if single else out

    def energy(self, U, V) -> np.ndarray:
        """``½vᵀM_Lv + ½c²uᵀKu + s·1ᵀM_L(1 − cos u)`` per sample (conserved up to O(dt²))."""
        U, V = np.atleast_2d(U), np.atleast_2d(V)
        m = self.mass.diagonal()
        return (0.5 * np.einsum("bi,i,bi->b", V, m, V)
                + 0.5 * self.c**2 * np.einsum("bi,bi->b", U, (self.K @ U.T).T)
                + self.strength * (1.0 - np.cos(U)) @ m)

    # -- Physics ------------------------------------------------------------------------------------
    def _forward(self, X):
        U, V = self._march(np.ascontiguousarray(X.T), np.zeros((X.shape[1], X.shape[0])))
        self._last = (X.copy(), U, V)  # a vjp at bitwise the same X (the bridge's backward) starts here
        return np.array(U.T, order="C")  # a copy: the caller may write into it

    def _final(self, U0):
        """``(u_T, v_T)`` (columns) from ``(u₀, 0)``: the last forward run's if ``U0`` holds bitwise its
        input, else marched."""
        last = self._last
        if last is not None and last[0].shape == U0.T.shape and np.array_equal(last[0], U0.T):
            return last[1], last[2]
        return self._march(U0, np.zeros_like(U0))

    def _jvp(self, X, Vdot):
        dU, = self._by_columns(self._jvp_block, np.ascontiguousarray(X.T), np.ascontiguousarray(Vdot.T))
        return np.ascontiguousarray(dU.T)

    def _jvp_block(self, U, dU):
        V, dV = np.zeros_like(U), np.zeros_like(U)
        h = self.dt
        a, AdU = None, self._A(U, dU)
        for _ in range(self.steps):  # the products at the step's end start the next one
            dVh = dV - 0.5 * h * AdU
            U, V, a = self.step(U, V, 1.0, a)
            dU = dU + h * dVh
            AdU = self._A(U, dU)
            dV = dVh - 0.5 * h * AdU
        return (dU,)

    def _vjp(self, X, R):
        U0 = np.ascontiguousarray(X.T)
        if self.recompute == "store":
            traj = [U0]
            self._march(U0, np.zeros_like(U0), keep=traj)
            Ub, = self._sweep((traj[j] for j in range(self.steps, -1, -1)), np.ascontiguousarray(R.T))
        else:
            Ub, = self._by_columns(lambda ut, vt, r: self._sweep(self._reversed(ut, vt), r),
                                   *self._final(U0), np.ascontiguousarray(R.T))
        return np.ascontiguousarray(Ub.T)

    def _sweep(self, states, Ub, A_T=None):
        """The transposed steps from ``ū = Ub``, ``v̄ = 0`` over ``states`` ``u_n, …, u₀``; ``A_T(u, w)``:
        ``A(u)ᵀ w`` on ``Ub``'s shape (default :meth:`_A_T`, one cotangent per column)."""
        h, A_T = self.dt, A_T or self._A_T
        Vb = np.zeros_like(Ub)
        U1 = next(states)
        AVb = A_T(U1, Vb)
        for U in states:  # step u -> u1, transposed; its last product starts the step before
            Ub = Ub - 0.5 * h * AVb
            Vb = Vb + h * Ub
            AVb = A_T(U, Vb)
            Ub = Ub - 0.5 * h * AVb
        return (Ub,)

    def jacobian(self, X) -> np.ndarray:
        """The Jacobians ``P'(x_b)`` of the rows of ``X`` ``(B, N)``, ``(B, N, N)``: :meth:`_vjp`'s transposed
        steps on all ``N`` unit cotangents of each row at once (``ū`` ``(N, B, N)``), over the states
        recomputed backwards from the final state as the vjp does (one run, not one per cotangent)."""
        A, _ = batch(X, self.n_in, "X")
        n, B = self.n_in, A.shape[0]
        Ub = np.ascontiguousarray(np.broadcast_to(np.eye(n)[:, None, :], (n, B, n)))

        def A_T(U, W):  # A(u)ᵀ w on k cotangents per column, W (N, B, k)
            out = (self.K @ (self.qminv * W.reshape(n, -1))).reshape(W.shape)
            out += _scaled(torch.cos, U, self.strength)[:, :, None] * W
            return out

        Ub, = self._sweep(self._reversed(*self._final(np.ascontiguousarray(A.T))), Ub, A_T)
        return np.ascontiguousarray(Ub.transpose(1, 2, 0))

    def jacobian_bytes(self, B: int) -> int:
        """The memory of :meth:`jacobian` on ``B`` rows, about: four ``(N, B, N)`` float64 arrays."""
        return 4 * 8 * B * self.n_in * self.n_out

    def _reversed(self, U, V):
        """``u_n, u_{n−1}, …, u₀`` by stepping back from ``(u_n, v_n)``."""
        yield U
        a = None
        for _ in range(self.steps):
            U, V, a = self.step(U, V, -1.0, a)
            yield U

    def __repr__(self):
        return (f"SineGordon(N={self.n_in}, c={self.c}, T={self.t_end}, steps={self.steps}, "
                f"strength={self.strength}, dt/dt_max={self.dt / self.dt_max:.2f})")
