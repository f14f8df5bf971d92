"""Generalized eigenpairs ``K φ = λ M φ`` of the lowest modes, M-orthonormal (``ΦᵀMΦ = I``).

Small problems use a dense ``scipy.linalg.eigh`` (all modes, exact to rounding);
large ones ``scipy.sparse.linalg.eigsh`` in shift-invert mode about ``sigma``
(slightly below 0, so a singular Neumann ``K`` is fine), doubling the number of
requested modes until ``enough(lam)`` (the ascending eigenvalues found so far) says the cut-off was passed.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ..errors import TooManyModes  # noqa: F401  (re-exported)

DENSE_MAX = 1500


def lowest_modes(M, K, enough, max_fraction: float = 0.5, dense_max: int | None = None):
    """Return ``(lam, Phi)`` sorted ascending, covering at least the modes ``enough`` needs.

    ``enough(lam) -> bool`` gets the ascending eigenvalues computed so far and
    says whether they reach past the cut-off.
    """
    N = M.shape[0]
    if N <= (DENSE_MAX if dense_max is None else dense_max):
        lam, Phi = la.eigh(K.toarray(), M.toarray())
        return lam, Phi
    # shift just below zero: scale-aware, keeps K - σM SPD for Neumann problems
    sigma = -1e-8 * float(K.diagonal().mean() / M.diagonal().mean())
    k = min(64, N - 2)
    while True:
        lam, Phi = sla.eigsh(sp.csc_matrix(K), k, sp.csc_matrix(M), sigma=sigma, which="LM", tol=0)
        order = np.argsort(lam)
        lam, Phi = lam[order], Phi[:, order]
        if enough(lam):
            return lam, Phi
        if k >= max_fraction * N:
            raise TooManyModes(
                f"the modal backend would need more than {k} of {N} modes "
                f"(> {max_fraction:.0%}); use backend='steps'"
            )
        k = min(2 * k, N - 2)


def largest_eigenvalue(M, K) -> float:
    """``λ_max`` of ``K φ = λ M φ`` (relative accuracy ~1e-8)."""
    if M.shape[0] <= DENSE_MAX:
        top = [M.shape[0] - 1] * 2
        return float(la.eigh(K.toarray(), M.toarray(), eigvals_only=True, subset_by_index=top)[0])
    return float(sla.eigsh(sp.csc_matrix(K), 1, sp.csc_matrix(M), which="LA", tol=1e-8)[0][0])
