"""The physics seen through a fixed decoder, and the local inverse whose change stays in the decoder's span.

A network whose output is ``x = D c`` for a fixed decoder ``D`` (``N × k``: :func:`pdeinv.nets.reduced`,
the prior's leading principal components) can only produce fields in ``span D``. Its observations are
``y = P D c = P̂ c`` with ``P̂ = P D`` (``m × k``), whose thin SVD ``P̂ = Q diag(s) Vᵀ`` costs ``k``
forward calls and one small SVD (:func:`decoded_svd`; HIG's Kronecker route uses the same factor).

:class:`DecoderTikhonov` is the local inverse ``P⁻¹_(x₀, P x₀)`` whose change is the regularized
solve *in that span*:

    Δc = argmin ‖P̂ Δc − (y − P x₀)‖² + α‖Δc‖² = V diag(s / (s² + α)) Qᵀ (y − P x₀),
    x̃  = x₀ + D Δc.

It keeps the local-inverse contract (:mod:`pdeinv.inverse.protocol`): at ``y = P x₀`` the residual is
exactly zero and ``x̃ = x₀``, whatever ``x₀`` is (in ``span D`` or not). The prior shapes the
regularizer (the change lives in ``span D``, weighted by ``‖Δc‖``), it does not replace the current
prediction: ``x₀``'s component outside ``span D`` and, inside it, along the null space of ``P̂`` is
carried over unchanged. ``P x₀`` is one forward call, or none when the caller passes it
(:meth:`DecoderTikhonov.local`; SIP does, it has computed ``P x`` for its loss): ``P̂ c₀`` from the
SVD would do only for ``x₀ ∈ span D``, and even then leaves a rounding residue at ``y = P x₀``.

Why it must be local: the global map ``x̃ = D V diag(s/(s²+α)) Qᵀ y`` ignores ``x₀``, is off ``x₀`` at
``y = P x₀``, and turns SIP with η = 1 into a regression onto one fixed target. For
``x₀ = D c₀ ∈ span D`` the two differ by

    x̃_local − x̃_global = D (I − V diag(s²/(s²+α)) Vᵀ) c₀  →  D (I − V Vᵀ) c₀   (α → 0),

the component of ``c₀`` in the null space of ``P̂``, which the local map keeps and the global one zeroes
(plus the bias ``α/(s²+α)`` per kept mode, below 1e-2 for ``s`` above 1e-11·s_max at the default α).
SIP's fixed point ``x̃ = x`` is ``Qᵀ(y* − P x) = 0``: the least-squares fit through ``P̂``, with α
setting only the speed (iterated Tikhonov), not a bias. On the reduced network the proxy gradient
``x − x̃ = −D Δc`` has no component along ``null P̂``, so coefficients there keep their initial value
(zero: the head starts at zero); the effective cut-off after ``k`` steps is ``≈ α/k``. Where a
regularized fixed point is better than the least-squares one (heat_3d, heat_cavity_3d), the noise-free
target puts that regularization back where the contract allows it, in what is matched: the
rounding-level Tikhonov filter in the basis of ``P̂`` (``t = Q diag(s²/(s²+α)) Qᵀ y*``,
:meth:`pdeinv.methods.targets.SpectralWiener.rounding`, the trainer's default).

α is rounding-level, ``α = rel_alpha · s_max²`` (1e-24: singular values resolved to 1e-12 of the
largest, so float64 rounding in the residual (ε ≈ 2e-16 of ``‖y‖``) reaches a coefficient amplified by at
most ``ε/(2·1e-12) ≈ 1e-4``; noisy observations are denoised before, by the trainer's target,
:mod:`pdeinv.methods.targets`, in the same basis; 1e-16 left heat_2d's x-error ~5× higher).
SIP with it converges to the least-squares fit *through the physics* inside the decoder's span:
the prior's principal components then extrapolate into modes the observation barely sees, where the
full-space inverse followed by SIP's Euclidean proxy projects a field that has nothing there
(heat_plate noise-free: x-error 0.0101 against 0.0496).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg as sla

from ._inputs import given_forward, out, pair

#: α relative to s_max² of the decoded physics (module docstring)
REL_ALPHA = 1e-24


class DecodedSVD(NamedTuple):
    """``P̂ = P D = Q diag(s) Vᵀ`` (thin SVD, zero singular values dropped)."""

    Q: np.ndarray  # (m, r)
    s: np.ndarray  # (r,)
    V: np.ndarray  # (k, r)

    def forward(self, C) -> np.ndarray:
        """``P x`` for ``x = D c`` given the coefficients ``c`` (rows of ``C``): ``P̂ c = Q diag(s) Vᵀ c``."""
        return ((np.asarray(C, dtype=float) @ self.V) * self.s) @ self.Q.T


def decoded_svd(op, decoder) -> DecodedSVD:
    """``P̂``'s thin SVD from ``k`` forward calls; ``decoder``: the rows ``Dᵀ`` (``(k, N)``, numpy or
    torch), ``None`` for the identity (``N`` calls). Computed once per operator and decoder object (the
    trainer's target, SIP's inverse and HIG's step all ask for it). A fixed matrix ``P`` only: on nonlinear
    physics ``P`` of the decoder's rows is no linear map, and the call is refused."""
    from ..physics.nonlinear import require_linear

    require_linear(op, "the SVD of P on a decoder (decoded_svd)")
    cache = vars(op).setdefault("_decoded_svd", {})
    key = id(decoder)
    if key not in cache:  # the entry keeps the decoder alive: its id stays unique
        cache[key] = (decoder, _decoded_svd(op, decoder))
    return cache[key][1]


def known_svd(op, decoder) -> DecodedSVD | None:
    """:func:`decoded_svd` of ``op`` and ``decoder`` where this run already computed it, else ``None`` (no
    forward calls): what a caller that could also run the physics asks."""
    entry = vars(op).get("_decoded_svd", {}).get(id(decoder))
    return None if entry is None or entry[0] is not decoder else entry[1]


def _decoded_svd(op, decoder) -> DecodedSVD:
    P_hat = np.asarray(op.forward(decoded_rows(decoder, op.n_in)), dtype=float).T  # (m, k)
    Q, s, Vt = np.linalg.svd(P_hat, full_matrices=False)
    # the rank cut scales with the short side k, not with the mesh: heat_2d's closed-form decoder solve
    # kept 150 of P̂'s directions at 3 969 unknowns and 135 at 65 025 with max(m, k)·eps (x-error 0.00135,
    # 0.00250), 169 and 174 with k·eps (0.00125, 0.00134); α (rounding-level) damps what is left
    keep = s > s[0] * min(P_hat.shape) * np.finfo(float).eps if s.size and s[0] > 0 else np.zeros(0, bool)
    return DecodedSVD(Q[:, keep], s[keep], Vt[keep].T)


class DecoderTikhonov:
    """``P⁻¹_(x₀, Px₀)(y) = x₀ + D V diag(s/(s²+α)) Qᵀ (y − P x₀)``: the local inverse whose change is the
    Tikhonov solve in the decoder's span (module docstring). Declares
    :class:`~pdeinv.inverse.protocol.ReusesForward`: :meth:`local` takes ``P x₀`` from the caller."""

    def __init__(self, op, decoder, rel_alpha: float = REL_ALPHA):
        from .._checks import positive

        self.rel_alpha = positive(rel_alpha, "rel_alpha")
        self.op = op
        self.svd = decoded_svd(op, decoder)
        self.rows = decoded_rows(decoder, op.n_in)
        s = self.svd.s
        self.filter = s / (s**2 + self.rel_alpha * (s[0] ** 2 if s.size else 0.0))
        self._gram = self._gram_matrix = None  # the decoder rows' Gram and its factor, on first use

    def __call__(self, y, x0) -> np.ndarray:
        Y, X0, single = pair(y, x0, len(self.svd.Q), self.rows.shape[1])
        return out(self._step(Y, X0, self.op.forward(X0)), single)

    def local(self, y, x0, y0) -> np.ndarray:
        """``self(y, x0)`` given ``y0 = op.forward(x0)``: no forward call."""
        Y, X0, single = pair(y, x0, len(self.svd.Q), self.rows.shape[1])
        Y0 = given_forward(y0, X0, len(self.svd.Q))
        return out(self._step(Y, X0, Y0), single)

    def forward_in_span(self, X) -> np.ndarray:
        """``P x`` for fields ``x = D c`` of the decoder's span without running the physics: ``c`` by least
        squares on the decoder's rows, then :meth:`forward_coefficients` (``k`` forward calls paid once, at
        the SVD). Exact to rounding in the span (and up to the rank cut's ``k·eps`` relative); a field outside
        it loses its part outside. A wave scene at 29 929 unknowns: 1 024 rows by 50 Newmark steps take ~77 s;
        this, three products of the batch with ``(k, N)``-sized arrays."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        c = sla.cho_solve(self._gram_factor(), self.rows @ X.T).T
        return self.forward_coefficients(c)

    def forward_coefficients(self, C) -> np.ndarray:
        """``P x`` for ``x = D c`` given the coefficients ``c`` (rows of ``C``): ``P̂ c = Q diag(s) Vᵀ c``."""
        return self.svd.forward(C)

    def change_coefficients(self, R) -> np.ndarray:
        """``Δc = V diag(s/(s²+α)) Qᵀ r`` per row ``r`` of ``R``: the inverse's change ``x̃ − x₀ = D Δc`` for a
        residual ``r = y − P x₀`` (:meth:`local`), in the decoder's coordinates."""
        return ((np.asarray(R, dtype=float) @ self.svd.Q) * self.filter) @ self.svd.V.T

    @property
    def gram(self) -> np.ndarray:
        """``DᵀD`` (``k × k``, the decoder rows' Gram): ``‖D c‖² = cᵀ (DᵀD) c``."""
        if self._gram_matrix is None:
            self._gram_matrix = self.rows @ self.rows.T
        return self._gram_matrix

    def _gram_factor(self):
        if self._gram is None:
            self._gram = sla.cho_factor(self.gram)
        return self._gram

    def _step(self, Y, X0, Y0) -> np.ndarray:
        return X0 + self.change_coefficients(Y - Y0) @ self.rows

    def __repr__(self):
        return f"DecoderTikhonov(k={self.rows.shape[0]}, r={len(self.svd.s)}, rel_alpha={self.rel_alpha:g})"


def decoded_rows(decoder, n: int) -> np.ndarray:
    """The decoder's rows ``Dᵀ`` as float64 numpy (the identity for ``None``)."""
    if decoder is None:
        return np.eye(n)
    import torch

    return np.asarray(decoder.detach().cpu().double().numpy() if isinstance(decoder, torch.Tensor)
                      else decoder, dtype=float)
