"""A truncated SVD from forward and adjoint products only: no dense ``P``, no dense Cholesky.

For an operator ``P`` (``m × N``) of numerical rank ``r ≪ min(m, N)`` — heat-like decay,
sensor records — the SVD in the problem's norms (``‖·‖_M`` in, ``‖·‖_{M_out}`` out) costs
about ``r`` forward and ``r`` adjoint runs instead of the ``N`` forward runs of
:func:`.compiled.matrix` (randomized range finder, Halko, Martinsson & Tropp 2011, §4.4):

1. **Range.** Probe ``Y = P Ω`` with Gaussian blocks; remove what the basis already has
   (``Y ← Y − Q QᵀM_out Y``, twice), then orthonormalize: Householder QR (stable whatever
   the decay of ``Y``'s columns) followed by one Cholesky QR in ``M_out`` (``QᵀM_outQ`` is as
   well conditioned as ``M_out``). Stop when a whole new block has M_out-norm
   ``≤ rtol·safety`` times the first block's: then ``‖(I − QQᵀM_out)P‖ ≲ rtol·‖P‖``.
2. **Rows.** ``B = QᵀM_out P`` by ``r`` adjoint runs (exact).
3. **Input side.** ``W``: an M-orthonormal basis of ``span(M⁻¹Bᵀ)`` (sparse solves with ``M``,
   the same QR pair); then ``B = (B W) WᵀM`` exactly.
4. **Small SVD.** ``B W = U s Vᵀ`` (``r × r``), so ``P ≈ (QU) diag(s) (WV)ᵀ M``:
   ``out = QU``, ``proj = M_out QU``, ``synth = WV``, ``In = M WV``; keep ``s ≥ rtol·s_max``.

``RankTooHigh`` when the range passes ``max_rank`` columns: a full-rank operator (a wave
field) is cheaper as a dense matrix, and the caller decides.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as sla


class RankTooHigh(Exception):
    """The range finder needed more than ``max_rank`` columns."""


def _mass(M, n: int):
    return sp.identity(n, format="csr") if M is None else sp.csr_matrix(M)


def _orthonormal(Y: np.ndarray, M, Q: np.ndarray | None = None) -> np.ndarray:
    """An M-orthonormal basis of ``span(Y)``, M-orthogonal to ``Q`` (Householder QR, then Cholesky QR)."""
    for _ in range(2):
        if Q is not None and Q.shape[1]:
            Y = Y - Q @ (Q.T @ (M @ Y))
    E, _ = la.qr(Y, mode="economic")
    if Q is not None and Q.shape[1]:
        E = E - Q @ (Q.T @ (M @ E))
    R = la.cholesky(E.T @ (M @ E))
    return la.solve_triangular(R, E.T, trans="T").T


def svd_from_products(forward, adjoint, n_in: int, n_out: int, M=None, M_out=None, rtol: float = 1e-12,
                      max_rank: int | None = None, block: int = 32, safety: float = 1e-2,
                      seed: int = 0) -> dict:
    """The arrays ``g, In, out, proj, synth`` of :class:`.compiled.SVD` from ``forward(X)`` (rows
    ``(b, N) → (b, m)``) and ``adjoint(R)`` (``(b, m) → (b, N)``); module docstring."""
    if not 0 < rtol < 1:
        raise ValueError(f"rtol={rtol!r} is not allowed; expected 0 < rtol < 1")
    Mi, Mo = _mass(M, n_in), _mass(M_out, n_out)
    cap = min(n_in, n_out) if max_rank is None else min(max_rank, n_in, n_out)
    rng = np.random.default_rng(seed)
    Q, first = np.zeros((n_out, 0)), None
    full = min(n_in, n_out)
    while Q.shape[1] < full:
        Y = forward(rng.standard_normal((min(block, full - Q.shape[1]), n_in))).T
        for _ in range(2):
            Y -= Q @ (Q.T @ (Mo @ Y))
        size = np.sqrt(np.einsum("ij,ij->j", Y, Mo @ Y)).max()
        first = size if first is None else first
        if Q.shape[1] and size <= safety * rtol * first:
            break
        if Q.shape[1] + Y.shape[1] > cap:
            raise RankTooHigh(f"more than {cap} singular values above rtol={rtol:g}")
        Q = np.hstack([Q, _orthonormal(Y, Mo, Q)])
    B = adjoint((Mo @ Q).T)  # (r, N): QᵀM_out P
    W = _orthonormal(sla.splu(sp.csc_matrix(Mi)).solve(np.ascontiguousarray(B.T)), Mi)
    U, s, Vt = np.linalg.svd(B @ W, full_matrices=False)
    keep = s >= rtol * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
    out, synth = Q @ U[:, keep], W @ Vt[keep].T
    return {"g": s[keep], "In": np.ascontiguousarray(Mi @ synth), "out": np.ascontiguousarray(out),
            "proj": np.ascontiguousarray(Mo @ out), "synth": np.ascontiguousarray(synth)}
