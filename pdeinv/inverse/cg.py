"""Matrix-free regularized solve: block CG on the M-weighted normal equations.

For any linear operator ``P`` (Euclidean ``forward``/``adjoint``), an input mass
matrix ``M`` and an observation-space mass matrix ``M_out``, the change

    Δx = argmin ½‖PΔx − (y − y₀)‖²_{M_out} + ½α‖Δx‖²_M,      y₀ = P x₀,

solves the normal equations

    (Pᵀ M_out P + α M) Δx = Pᵀ M_out (y − y₀).

We run preconditioned CG with the exact ``M⁻¹`` (one sparse factorization of
``M``, reused): the preconditioned operator is ``P*P + αI`` with the M-adjoint
``P* = M⁻¹PᵀM_out``, whose spectrum is ``{g² + α}`` for the heat operator. So
CG's iteration count depends only on how many well-separated ``g²`` lie above
α (fast for smoothing operators), not on the mesh's mass-matrix conditioning
(which a lumped-mass diagonal would leave in). Each column has its own α; the
columns share every operator call (one batched ``forward`` + one batched
``adjoint`` per iteration, on the columns not yet converged). Column ``b``
stops when ``‖r_b‖_{M⁻¹} ≤ rtol·‖rhs_b‖_{M⁻¹}``.

Cost in operator applications (``forward`` ≈ ``adjoint`` for our schemes):
``1`` forward (``y₀``; none when the caller passes it, :meth:`TikhonovCG.local`) + ``1`` adjoint
(right-hand side) + ``it`` × (forward + adjoint), plus one adjoint per warm restart during a
discrepancy search.
``last_info`` reports the iterations, relative residuals, calls and the
column-weighted cost in forward-solve units (one unit = one batched forward).
"""

from __future__ import annotations

import numpy as np

from .._checks import count, positive
from ..fem.solvers import SuperLU
from ..physics.capabilities import output_mass
from ._inputs import given_forward, mass_norms, mass_trace, out, pair
from .alpha import Fit, as_rule

#: memory the reorthogonalization history may take, in GB: each iteration keeps ``r`` and ``M⁻¹r`` of the
#: batch, two ``(B, N)`` float64 arrays (SIP's full batch of 1024 at N = 3·10⁴: 0.5 GB per iteration, ~35
#: GB over 70 iterations unbounded); beyond the cap only the most recent iterations are kept (local
#: reorthogonalization: the oldest residuals, whose directions CG resolved first, are dropped first)
REORTH_GB = 1.0


class TikhonovCG:
    """``P⁻¹_(x₀, Px₀)(y) = x₀ + Δx`` with Δx from block PCG (module docstring).

    ``M``: input mass (sparse SPD, or ``None`` for the identity); ``M_out``:
    observation mass (``"auto"``: ``M`` when ``op`` declares field observations,
    :func:`~pdeinv.physics.capabilities.observes_field`, else the identity);
    ``alpha``: a number or a rule; ``scale``: ``λ_max(P*P)``, the unit of
    relative α rules (estimated by power iteration on first use if omitted). Declares
    :class:`~.protocol.ReusesForward`: :meth:`local` takes ``P x₀`` from the caller.
    """

    def __init__(self, op, M=None, alpha=1e-8, M_out="auto", rtol=1e-10, maxiter=1000,
                 scale=None, mass_solver=SuperLU, reorth=True, reorth_gb: float = REORTH_GB):
        self.reorth = reorth
        self.reorth_gb = positive(reorth_gb, "reorth_gb")
        self.op, self.M = op, M
        self.M_out = output_mass(op, M) if isinstance(M_out, str) else M_out
        self.rule = as_rule(alpha)
        self.rtol = positive(rtol, "rtol")
        self.maxiter = count(maxiter, "maxiter")
        self._scale = None if scale is None else positive(scale, "scale")
        self._Minv = None if M is None else mass_solver(M)
        self._inside = False
        self.last_info: dict = {}

    def history_length(self, B: int) -> int:
        """How many iterations of the reorthogonalization history fit in ``reorth_gb`` for ``B`` rows
        (at least 2: reorthogonalizing against the last two residuals keeps most of its benefit)."""
        return max(2, int(self.reorth_gb * 1e9 // (16 * B * self.op.n_in))) if self.reorth else 0

    def memory_bytes(self, B: int) -> float:
        """Bytes a solve of ``B`` rows allocates: about ten ``(B, N)`` / ``(B, m)`` float64 work arrays
        (``X``, ``PX``, ``b``, residual, search direction, ``M⁻¹r``, products, the caller's ``x₀, y, y₀``)
        and the bounded reorthogonalization history (:meth:`history_length`)."""
        n, m = self.op.n_in, self.op.n_out
        return 8.0 * B * (7 * n + 4 * m) + 16.0 * B * n * min(self.history_length(B), self.maxiter + 1)

    # -- linear algebra on batch-first rows ------------------------------------------
    def _mass(self, M, X):
        return X if M is None else np.asarray((M @ X.T).T)

    def _precond(self, R):
        return R.copy() if self._Minv is None else np.ascontiguousarray(self._Minv.solve(R.T).T)

    def _count(self, kind, rows):
        self._calls[kind] += 1
        self._units[kind] += rows / self._B

    def _normal(self, D, alpha):
        """``(PᵀM_outP + αM) D`` and ``P D``."""
        PD = self.op.forward(D)
        self._count("forward", len(D))
        AD = self.op.adjoint(self._mass(self.M_out, PD))
        self._count("adjoint", len(D))
        return AD + alpha[:, None] * self._mass(self.M, D), PD

    def _reset(self, B: int) -> None:
        self._B, self._it = B, np.zeros(B, dtype=int)
        self._calls = {"forward": 0, "adjoint": 0}
        self._units = {"forward": 0.0, "adjoint": 0.0}

    def solve(self, b, alpha, X=None, PX=None):
        """``(X, PX, rel)``: PCG on ``(PᵀM_outP + αM) X = b`` for every row of ``b`` (``α`` one per
        row or one for all), from ``X`` (with ``PX = P X``; zeros if omitted), updated in place;
        ``rel`` the relative residuals ``‖r‖_{M⁻¹}/‖b‖_{M⁻¹}``. Usable on its own."""
        b = np.atleast_2d(np.asarray(b, dtype=float))
        alpha = np.broadcast_to(np.asarray(alpha, dtype=float), (len(b),)).copy()
        if X is None:
            X, PX = np.zeros((len(b), self.op.n_in)), np.zeros((len(b), self.op.n_out))
        if not self._inside:
            self._reset(len(b))
        self._bnorm = np.sqrt(np.abs(np.einsum("bi,bi->b", b, self._precond(b))))
        if np.any(X):
            self._count("adjoint", len(X))
            Res = b - self.op.adjoint(self._mass(self.M_out, PX)) - alpha[:, None] * self._mass(self.M, X)
        else:
            Res = b.copy()
        Z = self._precond(Res)
        rz = np.einsum("bi,bi->b", Res, Z)
        goal = self.rtol * self._bnorm
        active = np.sqrt(np.abs(rz)) > goal
        D, it = Z, np.zeros(len(b), dtype=int)
        hist = [_snapshot(Res, Z, np.arange(len(b)))] if self.reorth else []
        keep = self.history_length(len(b))
        for _ in range(self.maxiter):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            AD, PD = self._normal(D[idx], alpha[idx])
            a = rz[idx] / np.einsum("bi,bi->b", D[idx], AD)
            X[idx] += a[:, None] * D[idx]
            PX[idx] += a[:, None] * PD
            Res[idx] -= a[:, None] * AD
            if self.reorth:
                Res[idx] = _reorthogonalize(Res[idx], hist, idx)
            Zi = self._precond(Res[idx])
            if self.reorth:
                hist.append(_snapshot(Res, Zi, idx))
                del hist[:-keep]  # bounded memory (REORTH_GB): the oldest iterations go first
            rz_new = np.einsum("bi,bi->b", Res[idx], Zi)
            D[idx] = Zi + (rz_new / rz[idx])[:, None] * D[idx]
            rz[idx] = rz_new
            it[idx] += 1
            active[idx] = np.sqrt(np.abs(rz_new)) > goal[idx]
        self._it += it
        rel = np.sqrt(np.abs(rz)) / np.where(self._bnorm > 0, self._bnorm, 1.0)
        return X, PX, rel

    # -- the inverse simulator --------------------------------------------------------
    def __call__(self, y, x0) -> np.ndarray:
        Y, X0, single = pair(y, x0, self.op.n_out, self.op.n_in)
        return self._run(Y, X0, None, single)

    def local(self, y, x0, y0) -> np.ndarray:
        """``self(y, x0)`` given ``y0 = op.forward(x0)`` (:class:`~.protocol.ReusesForward`): one forward
        call fewer."""
        Y, X0, single = pair(y, x0, self.op.n_out, self.op.n_in)
        return self._run(Y, X0, given_forward(y0, X0, self.op.n_out), single)

    def _run(self, Y, X0, Y0, single):
        B = Y.shape[0]
        self._reset(B)
        self._inside = True
        try:
            return self._call(Y, X0, Y0, single, B)
        finally:
            self._inside = False

    def _call(self, Y, X0, Y0, single, B):
        if Y0 is None:
            Y0 = self.op.forward(X0)
            self._count("forward", B)
        R = Y - Y0
        b = self.op.adjoint(self._mass(self.M_out, R))
        self._count("adjoint", B)
        state = {"X": np.zeros_like(X0), "PX": np.zeros_like(R), "alpha": None, "rel": np.zeros(B)}

        def run(alpha):
            if state["alpha"] is None or not np.array_equal(alpha, state["alpha"]):
                state["X"], state["PX"], state["rel"] = self.solve(b, alpha, state["X"], state["PX"])
                state["alpha"] = alpha.copy()
            return state

        def rho(alpha):
            return mass_norms(self.M_out, run(alpha)["PX"] - R)

        fit = Fit(rho, Y, mass_trace(self.M_out, Y.shape[1]), lambda: self.scale)
        alpha = np.asarray(self.rule.select(fit), dtype=float)
        s = run(alpha)
        self.last_info = {
            "alpha": alpha, "iterations": self._it.copy(), "residual": s["rel"].copy(),
            "converged": bool(np.all(s["rel"] <= self.rtol)),
            "calls": dict(self._calls),
            "forward_units": self._units["forward"] + self._units["adjoint"],
        }
        return out(X0 + s["X"], single)

    @property
    def scale(self) -> float:
        """``λ_max(P*P)`` with ``P* = M⁻¹PᵀM_out`` (30 power iterations on one column)."""
        if self._scale is None:
            v = np.random.default_rng(0).standard_normal((1, self.op.n_in))
            lam = 0.0
            for _ in range(30):
                v /= mass_norms(self.M, v)[0]
                w = self._precond(self.op.adjoint(self._mass(self.M_out, self.op.forward(v))))
                lam = float(np.einsum("bi,bi->b", v, self._mass(self.M, w))[0])
                v = w
            self._scale = lam
        return self._scale

    def __repr__(self):
        return f"TikhonovCG(op={self.op!r}, alpha={self.rule!r}, rtol={self.rtol:g})"



def _reorthogonalize(R, hist, idx):
    """Project out of the new residuals ``R`` (rows ``idx``) all earlier ones, M⁻¹-orthogonally.

    Exact PCG residuals satisfy ``r_iᵀM⁻¹r_j = 0``; in floating point they drift
    apart and CG re-discovers eigenvalues it already resolved (seen: 167
    iterations instead of 40 on the 2-D heat operator, α=1e-8, rtol=1e-10).
    Classical Gram–Schmidt, applied twice.
    """
    for _ in range(2):
        for Rj, Zj, zr in hist:
            R -= (np.einsum("bi,bi->b", Zj[idx], R) / zr[idx])[:, None] * Rj[idx]
    return R


def _snapshot(Res, Zi, idx):
    """``(r, M⁻¹r, rᵀM⁻¹r)`` for the rows ``idx`` (zero rows elsewhere, which project out nothing)."""
    R, Z, zr = np.zeros_like(Res), np.zeros_like(Res), np.ones(len(Res))
    R[idx], Z[idx] = Res[idx], Zi
    zr[idx] = np.einsum("bi,bi->b", Res[idx], Zi)
    zr[zr == 0] = 1.0
    return R, Z, zr
