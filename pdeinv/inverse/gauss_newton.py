"""A local inverse for nonlinear physics: one regularized Gauss–Newton step from ``x₀``.

For ``J = P'(x₀)`` (per row: each sample has its own tangent), input mass ``M`` and observation
mass ``M_out``,

    Δx = argmin ½‖J Δx − (y − y₀)‖²_{M_out} + ½α‖Δx‖²_M,   y₀ = P(x₀),   x̃ = x₀ + Δx,

i.e. ``(Jᵀ M_out J + α M) Δx = Jᵀ M_out (y − y₀)``, solved by CG preconditioned with ``M⁻¹``
(as :class:`~.cg.TikhonovCG` for linear ``P``), every row with its own ``J`` through the
physics' ``jvp``/``vjp`` at ``x₀`` — or, when the physics offers ``linearize(x₀)`` (a tangent kept
for many products, e.g. :meth:`pdeinv.physics.reaction.ReactionHeat.linearize`: stored trajectory
and factorizations, no Newton), through that, in chunks of the rows it declares it keeps its fastest
tangent for (``linearize_rows``; every row's solve is its own). The contract holds exactly: at ``y = y₀`` the
right-hand side is zero and ``x̃ = x₀``.

``α = rel_alpha · λ``, ``λ = λ_max(M⁻¹Jᵀ M_out J)`` of the tangent at 0 (power iteration once, on
first use): the filter cut-off sits at ``√rel_alpha`` of the largest gain, as
:func:`~pdeinv.inverse.default_alpha` does for linear physics. CG stops at ``rtol`` or ``maxiter``
(its semi-convergence regularizes too). ``last_info`` reports iterations and residuals.
"""

from __future__ import annotations

import numpy as np

from .._checks import batch, count, positive
from ..fem.solvers import SuperLU
from ..physics.capabilities import output_mass


class _AtX:
    """``jvp``/``vjp`` at fixed ``x₀`` through the physics (no kept tangent)."""

    def __init__(self, op, X0):
        self.op, self.X0 = op, X0

    def jvp(self, V):
        return self.op.jvp(self.X0, V)

    def vjp(self, R):
        return self.op.vjp(self.X0, R)


class GaussNewtonInverse:
    """``P⁻¹_(x₀, P(x₀))(y) = x₀ + Δx``, the regularized Gauss–Newton step (module docstring)."""

    def __init__(self, op, M, rel_alpha=1e-8, rtol=1e-6, maxiter=50):
        self.op, self.M = op, M
        self.M_out = output_mass(op, M)
        self.rel_alpha = positive(rel_alpha, "rel_alpha")
        self.rtol, self.maxiter = positive(rtol, "rtol"), count(maxiter, "maxiter")
        self.M_lu = SuperLU(M.tocsc())
        self._lam = None
        self.last_info = {}

    def _m(self, A, R):  # rows times a mass (None: identity)
        return R if A is None else (A @ R.T).T

    def _minv(self, R):
        return np.ascontiguousarray(self.M_lu.solve(np.ascontiguousarray(R.T)).T)

    def _tangent(self, X0):
        if self.op.linearize is not None:  # declared by the physics (pdeinv.physics.nonlinear)
            return self.op.linearize(X0)
        return self.op.forward(X0), _AtX(self.op, X0)

    def scale(self) -> float:
        """``λ_max(M⁻¹ P'(0)ᵀ M_out P'(0))`` by 20 power iterations (cached)."""
        if self._lam is None:
            rng = np.random.default_rng(0)
            v = rng.standard_normal((1, self.op.n_in))
            _, T = self._tangent(np.zeros_like(v))
            lam = 0.0
            for _ in range(20):
                v /= np.sqrt(float((v * self._m(self.M, v)).sum()))
                w = self._minv(T.vjp(self._m(self.M_out, T.jvp(v))))
                lam, v = float((w * self._m(self.M, v)).sum()), w
            self._lam = lam
        return self._lam

    def __call__(self, y, x0) -> np.ndarray:
        Y, single = batch(y, self.op.n_out, "y")
        X0, _ = batch(x0, self.op.n_in, "x0")
        if Y.shape[0] != X0.shape[0]:
            raise ValueError(f"y has {Y.shape[0]} rows and x0 {X0.shape[0]}; expected one x0 per y")
        alpha = self.rel_alpha * self.scale()
        # rows in the chunks whose tangent the physics keeps at its fastest (declared ``linearize_rows``)
        size = (self.op.linearize_rows if self.op.linearize is not None else None) or Y.shape[0]
        chunks = [self._solve(Y[i:i + size], X0[i:i + size], alpha) for i in range(0, Y.shape[0], size)]
        self.last_info = {"iterations": max(c[1] for c in chunks), "alpha": alpha,
                          "relative_residual": max(c[2] for c in chunks), "chunks": len(chunks)}
        out = np.concatenate([c[0] for c in chunks])
        return out[0] if single else out

    def _solve(self, Y, X0, alpha) -> tuple[np.ndarray, int, float]:
        """One chunk of rows: ``(x₀ + Δx, CG iterations, largest relative residual)``."""
        Y0, T = self._tangent(X0)

        def normal(V):
            return T.vjp(self._m(self.M_out, T.jvp(V))) + alpha * self._m(self.M, V)

        b = T.vjp(self._m(self.M_out, Y - Y0))
        X = np.zeros_like(b)
        R = b.copy()
        Z = self._minv(R)
        Pd = Z.copy()
        rz = np.einsum("bi,bi->b", R, Z)
        rz0 = np.where(rz > 0, rz, 1.0)
        it = 0
        while it < self.maxiter and np.any(rz > self.rtol**2 * rz0):
            Q = normal(Pd)
            pq = np.einsum("bi,bi->b", Pd, Q)
            a = np.where(pq > 0, rz / np.where(pq > 0, pq, 1.0), 0.0)
            X += a[:, None] * Pd
            R -= a[:, None] * Q
            Z = self._minv(R)
            rz_new = np.einsum("bi,bi->b", R, Z)
            beta = np.where(rz > 0, rz_new / np.where(rz > 0, rz, 1.0), 0.0)
            Pd = Z + beta[:, None] * Pd
            rz = rz_new
            it += 1
        return X0 + X, it, float(np.sqrt(np.max(np.abs(rz) / rz0)))

    def __repr__(self):
        return f"GaussNewtonInverse({self.op!r}, rel_alpha={self.rel_alpha:g}, maxiter={self.maxiter})"
