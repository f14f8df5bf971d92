"""Generalized eigenpairs ``K φ = λ M φ`` of the lowest modes, M-orthonormal (``ΦᵀMΦ = I``).

Small problems use a dense ``scipy.linalg.eigh`` (all modes, exact to rounding);
large ones ``scipy.sparse.linalg.eigsh`` in shift-invert mode about ``sigma``
(slightly below 0, so a singular Neumann ``K`` is fine). The caller passes the
number of modes ``k`` it expects to need (the modal backend: Weyl's law plus a
margin); one call computes them and ``enough(lam)`` (the ascending eigenvalues)
checks that the cut-off was passed; only if not, ``k`` is doubled and eigsh
called again. Each ARPACK call costs about ``N·k²`` and dominates, so the first
guess matters: the former start at 64 modes with doubling took 4 calls (67 s)
where one call with the Weyl count takes 22 s (heat_2d, n=128, one thread).
ARPACK starts from a fixed random vector, so a build is reproducible.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ..errors import TooManyModes  # noqa: F401  (re-exported)

DENSE_MAX = 1500


def lowest_modes(M, K, enough, max_fraction: float = 0.5, dense_max: int | None = None, k: int = 64):
    """Return ``(lam, Phi)`` sorted ascending, covering at least the modes ``enough`` needs.

    ``enough(lam) -> bool`` gets the ascending eigenvalues computed so far and
    says whether they reach past the cut-off; ``k``: modes asked for by the first
    (sparse) call. ``TooManyModes`` once a call for ``≥ max_fraction·N`` modes was not enough.
    """
    N = M.shape[0]
    if N <= (DENSE_MAX if dense_max is None else dense_max):
        lam, Phi = la.eigh(K.toarray(), M.toarray())
        return lam, Phi
    # shift just below zero: scale-aware, keeps K - σM SPD for Neumann problems
    sigma = -1e-8 * float(K.diagonal().mean() / M.diagonal().mean())
    if not k >= 1:
        raise ValueError(f"k={k!r} modes requested; expected an integer >= 1")
    k = int(min(k, N - 2))
    v0 = np.random.default_rng(0).standard_normal(N)  # fixed: reproducible, and not M-orthogonal to any mode
    while True:
        lam, Phi = sla.eigsh(sp.csc_matrix(K), k, sp.csc_matrix(M), sigma=sigma, which="LM", tol=0, v0=v0)
        order = np.argsort(lam)
        lam, Phi = lam[order], Phi[:, order]
        if enough(lam):
            return lam, Phi
        if k >= max_fraction * N or k >= N - 2:
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
