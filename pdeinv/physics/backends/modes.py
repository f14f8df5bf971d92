"""Generalized eigenpairs ``K φ = λ M φ`` of the lowest modes, M-orthonormal (``ΦᵀMΦ = I``).

Small problems use a dense ``scipy.linalg.eigh`` (all modes, exact to rounding). Large ones
use a **block Krylov (block Lanczos) method in shift-invert mode** with full reorthogonalization:

    S = (K − σM)⁻¹ M   (self-adjoint in the M-inner product, eigenvalues μ = 1/(λ − σ)),
    Q = [Q₁ … Q_j] an M-orthonormal basis of span{Q₁, S Q₁, …, S^{j−1} Q₁},
    S Q = Q H + Q_{j+1} B Eᵀ   (H = QᵀMSQ, B from the last block's orthonormalization),

Rayleigh–Ritz ``H y = μ y`` gives ``λ = σ + 1/μ`` and ``φ = Q y`` with the exact residual norm
``‖S φ − μ φ‖_M = ‖B y_last‖`` (no extra solve). ``σ`` sits just below 0, so a singular
Neumann ``K`` is fine.

**Cost**: the first block is a random one after 8 block solves (:func:`_start_block`: ``K_j(S, S⁸R)``
damps the many high modes for no basis vectors); each new block is orthogonalized against
the last two blocks, where the recurrence puts it, then once against the whole basis (``2Nm²`` flops in
all; a second full pass gains nothing; only ``Q`` is stored, ``Qᵀ(MW)``
with a fresh sparse ``MW``); a check first counts the kept Ritz values by the inertia of ``H``'s band
(``H`` is block tridiagonal up to the reorthogonalization's rounding-level coefficients; a block
``LDLᵀ``, :func:`_count_above`, ``O(m b²)``), reads the Ritz values from the band (``O(m² b)``) only once
the count reaches the exact one, and the next check sits where the counts extrapolate to it; the kept
vectors come from ``eigh`` by divide and conquer, of the leading 60 % of ``H`` first and then of what is
left once its converged pairs are locked (:func:`_rayleigh_ritz`). Timings: benchmarks/notes/scaling.md.

**Stopping rule — accuracy of the operator, not of every eigenvector.** A caller passes
``log_gain(λ)``, the log of what each mode is multiplied by (``log|r(dtκλ)ⁿ|`` for heat),
and ``log_tol``: the modes with ``gain ≥ tol·max gain`` are kept. Mode ``i`` then enters
the operator with weight ``wᵢ = gainᵢ/max gain`` and its eigenvector error is about
``resᵢ/μᵢ`` (relative), so we stop once ``wᵢ·resᵢ/μᵢ ≤ eps`` for every kept Ritz pair.
The most amplified (lowest) modes converge first and most accurately; modes near the
cut-off only need to be roughly right, because they carry ``≈ tol``. A mode so close to
the cut-off that the Krylov space has not found it yet carries ``≈ tol`` as well.

Why not ARPACK (``eigsh``): it needs ``ncv ≈ 2k`` vectors and restarts with BLAS-2
reorthogonalization; this method's BLAS-3 block products were ~4× faster on heat_2d at n=128.
``tests/test_modes.py`` checks the modes against the dense solver and the operator against
time stepping. Block starts are seeded: a build
is reproducible.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ...errors import TooManyModes

DENSE_MAX = 1500
#: unknowns up to which the dense solver is still offered when the Krylov basis would be too large
#: (``k > N/2``, or :func:`krylov_flops` above the dense ``9N³``): up to this size a dense generalized
#: ``eigh`` still costs less than the dense operator by stepping or its SVD (heat_3d n=16: 10 s against 43 s)
DENSE_EIGH_MAX = 6000


def krylov_flops(N: int, k: float) -> float:
    """Cost of the block Krylov method for ``k`` expected modes (the caller's count with its margin), in
    flops at the rate of the dense ``eigh`` (the ``9N³`` it is weighed against), block solves apart:
    a basis of ``m = min(N, 1.7k)`` vectors, ``4.8Nm² + 5.3m³ + 2940Nm`` — the basis
    orthogonalized once (``2Nm²``) and the Ritz vectors ``Q Y`` (``2Nmk``), the final ``eigh`` of ``H``
    (``m × m``, memory-bound), the per-vector work of blocks of 64 (Cholesky QR, the local pass, ``M``
    products, fresh pages). The coefficients are a relative least-squares fit to the eigensolve's time
    less its solves on heat_3d n=16–24 and heat_2d n=128–256 (benchmarks/notes/scaling.md), the dense
    ``eigh`` of heat_3d n=16 fixing the rate."""
    m = min(N, 1.7 * k)
    return 4.8 * N * m**2 + 5.3 * m**3 + 2940 * N * m


def route(N: int, k: float) -> str | None:
    """How :func:`lowest_modes` finds about ``k`` of ``N`` modes: ``'dense'`` (``eigh``, about
    ``9N³`` flops), ``'krylov'`` (the block Krylov method, :func:`krylov_flops`, offered for
    ``k ≤ N/2``) or ``None`` (neither is offered)."""
    if N <= DENSE_MAX:
        return "dense"
    krylov = krylov_flops(N, k) if k <= N / 2 else None
    if N <= DENSE_EIGH_MAX and (krylov is None or 9 * N**3 < krylov):
        return "dense"
    return None if krylov is None else "krylov"


def _cholqr(W: np.ndarray, M) -> tuple[np.ndarray, np.ndarray]:
    """``W = Q R`` with ``QᵀMQ = I`` (Cholesky QR twice); ``LinAlgError`` if ``W`` is rank deficient."""
    R = np.eye(W.shape[1])
    for _ in range(2):
        Rk = la.cholesky(W.T @ (M @ W))
        W = la.solve_triangular(Rk, W.T, trans="T").T
        R = Rk @ R
    return W, R


class _Basis:
    """A growing M-orthonormal basis ``Q`` (column blocks) of ``N`` rows. ``MQ`` is not kept: the passes
    take ``Qᵀ(MW)`` with a fresh sparse product ``MW`` per pass, instead of ``(MQ)ᵀW`` from a second ``N × m``
    array (heat_3d n=24: 350 MB less; first-touch page faults 1.2 → 0.5 s, the sparse products +0.2 s)."""

    def __init__(self, M, capacity: int):
        self.M = M
        self.Q = np.empty((M.shape[0], capacity), order="F")
        self.m = 0

    def append(self, V: np.ndarray) -> None:
        b = V.shape[1]
        if self.m + b > self.Q.shape[1]:
            grown = np.empty((self.Q.shape[0], 2 * self.Q.shape[1] + b), order="F")
            grown[:, :self.m] = self.Q[:, :self.m]
            self.Q = grown
        self.Q[:, self.m:self.m + b] = V
        self.m += b

    def orthogonalize(self, W: np.ndarray, local: int = 0) -> np.ndarray:
        """Remove the basis from ``W`` (in place); returns the coefficients ``C`` (``W ← W − Q C``).

        ``local = 0``: classical Gram–Schmidt twice against the whole basis. ``local > 0`` (a block
        Lanczos step, ``W = S Qⱼ``): first against the last ``local`` columns, where the recurrence
        puts all of ``W`` but rounding (``S Qⱼ = Qⱼ₋₁ Bⱼ₋₁ᵀ + Qⱼ Aⱼ + Qⱼ₊₁ Bⱼ``), then once against
        the whole basis: the second full pass removed nothing the first had not (its coefficients
        are at the rounding level once the large local ones are gone) and cost half the eigensolve
        at heat_3d n=24. Each pass takes ``MW`` afresh: updated as ``MW − (MQ)C`` it would carry the
        rounding of the large ``W`` before the pass into the small one after it (a powered start block
        makes ``S Q₁`` lie almost in ``Q₁``: orthogonality was lost at 1e-2)."""
        Q, C = self.Q[:, :self.m], np.zeros((self.m, W.shape[1]))
        whole = slice(0, self.m)
        for part in ((slice(max(0, self.m - local), self.m), whole) if local else (whole, whole)):
            Cp = Q[:, part].T @ (self.M @ W)
            W -= Q[:, part] @ Cp
            C[part] += Cp
        return C


def _rank_revealing(W, M, basis: _Basis, rng):
    """``W = V B`` with M-orthonormal ``V`` when ``W`` is rank deficient: its numerical range
    (eigenvalues of ``WᵀMW`` above ``1e-14·max``) plus fresh directions orthogonal to the basis."""
    s, U = la.eigh(W.T @ (M @ W))
    good = s > 1e-14 * s.max() if s.max() > 0 else np.zeros(len(s), bool)
    V = W @ (U[:, good] / np.sqrt(s[good]))
    B = np.zeros((W.shape[1], W.shape[1]))
    B[:good.sum()] = np.sqrt(s[good])[:, None] * U[:, good].T
    fresh = rng.standard_normal((W.shape[0], W.shape[1] - good.sum()))
    for _ in range(2):
        fresh -= V @ (V.T @ (M @ fresh))
        basis.orthogonalize(fresh)
    return np.hstack([V, _cholqr(fresh, M)[0]]) if fresh.shape[1] else V, B


def lowest_modes(M, K, log_gain, log_tol: float, k: int = 64, eps: float = 1e-12, block: int = 64,
                 max_fraction: float = 0.5, dense_max: int | None = None, seed: int = 0,
                 at_least: int = 0):
    """``(lam, Phi)`` ascending: every mode with ``gain ≥ tol·max gain`` (see the module docstring).

    ``log_gain(lam) -> array``: log of each mode's gain; ``log_tol``: log of the relative
    cut-off; ``k``: the modes expected (Weyl's law), which sizes the first basis; ``eps``:
    the operator accuracy aimed at; ``at_least``: the Krylov method does not stop before it keeps that
    many modes (the exact count below the cut-off, :func:`count_below`: without it, it stopped once with
    1 722 of heat_3d n=24's 1 820, the last ones near the cut not yet found). ``TooManyModes`` once
    more than ``max_fraction·N`` modes would be kept.
    """
    N = M.shape[0]
    dense = route(N, k) == "dense" if dense_max is None else N <= dense_max
    if dense:
        lam, Phi = la.eigh(K.toarray(), M.toarray())
    else:
        lam, Phi = _block_krylov(sp.csr_matrix(M), sp.csr_matrix(K), log_gain, log_tol, k, eps, block,
                                 max_fraction, seed, at_least)
    lg = log_gain(lam)
    keep = lg >= lg.max() + log_tol
    return lam[keep], Phi[:, keep]


def _block_krylov(M, K, log_gain, log_tol, k, eps, block, max_fraction, seed, at_least=0):
    from ...fem.solvers import default_solver  # here: solvers import torch lazily through cholespy

    if not k >= 1:
        raise ValueError(f"k={k!r} modes requested; expected an integer >= 1")
    N = M.shape[0]
    b = int(min(block, max(1, N // 8)))
    sigma = -1e-8 * float(K.diagonal().mean() / M.diagonal().mean())
    solve = default_solver(sp.csc_matrix(K - sigma * M)).solve
    basis = _Basis(M, min(N, 3 * k + b))
    H = np.zeros((0, 0))
    rng = np.random.default_rng(seed)
    V = _start_block(rng.standard_normal((N, b)), M, solve)
    band = b  # H is block tridiagonal: band b while every Bⱼ is triangular (Cholesky QR), else 2b − 1
    # Rayleigh–Ritz checks from 1.5k (k: the caller's count of kept modes, with its margin; the basis needs
    # ~1.9 times the kept modes: heat_3d n=24 kept 1 880 modes with 3 584 vectors), then where the Ritz
    # count, extrapolated linearly from the last two checks, reaches ``at_least``: the count is an inertia
    # of H's band (~0.03 s; the band's Ritz values 0.6 s at 3 584, a dense eigvalsh 4.9 s at 3 968), so
    # checks are cheap and the basis stops within a block or two of the size it needs
    check_at, last = min(N, max(2 * b, int(1.5 * k))), None
    while True:
        m, b = basis.m, V.shape[1]
        basis.append(V)
        W = solve(M @ V)
        C = basis.orthogonalize(W, local=2 * b)
        if H.shape[0] < m + b:  # grown geometrically: np.pad per block copied O(m²) each time
            grown = np.zeros((min(N, int(1.25 * (m + b)) + b),) * 2)
            grown[:m, :m] = H[:m, :m]
            H = grown
        H[:m + b, m:m + b] = C
        if basis.m == N:  # the basis spans everything: Rayleigh–Ritz is exact
            B = np.zeros((b, b))
        else:
            try:
                V, B = _cholqr(W, M)
            except la.LinAlgError:  # W (nearly) rank deficient: keep its range, fill up with fresh vectors
                V, B = _rank_revealing(W, M, basis, rng)
                band = 2 * b
        if basis.m >= check_at:
            found, q = _ritz(H, basis, B, sigma, log_gain, log_tol, max_fraction, at_least, eps,
                             band if basis.m < N else basis.m)
            if found is not None:
                return found
            check_at, last = min(N, _next_check(basis.m, q, last, at_least, b)), (basis.m, q)
        if basis.m == N:  # only reached with max_fraction ≥ 1 and every mode kept
            raise TooManyModes(f"every one of the {N} modes would be kept; use backend='steps'")
        if N - basis.m < 2 * b:  # finish with the whole complement of the basis (≤ 2 blocks)
            V, _ = _rank_revealing(np.zeros((N, N - basis.m)), M, basis, rng)
            band = basis.m


#: block solves applied to the random start block before the Krylov basis begins (:func:`_start_block`)
START_POWERS = 8


def _start_block(R: np.ndarray, M, solve, powers: int | None = None) -> np.ndarray:
    """The first Krylov block ``V₀ = orth(S^p R)`` (``S = (K − σM)⁻¹M``, ``p = START_POWERS``, an
    M-orthonormalization after every solve): subspace iteration on a random block before Lanczos.

    ``K_j(S, S^p R) ⊂ K_{j+p}(S, R)`` with ``jb`` instead of ``(j+p)b`` vectors: ``p`` more degrees of the
    Krylov polynomial for ``p`` block solves and no basis vectors. Mode ``i``'s component scales like
    ``μᵢ^p``: the thousands of high modes (small ``μ``) are damped before the basis has to resolve them.
    Too many powers lose the modes near the cut-off: relative to the block's ``b``-th mode they fall like
    ``(μ_c/μ_b)^p`` and drop to the rounding level; ``p = 8`` needed the fewest vectors on heat_3d n=24."""
    V, _ = _cholqr(R, M)
    for _ in range(START_POWERS if powers is None else powers):
        try:
            V, _ = _cholqr(solve(M @ V), M)
        except la.LinAlgError:  # S far from well conditioned on the block (a singular Neumann K: μ₁ ≈ 1/|σ|)
            break
    return V


def _next_check(m: int, q: int, last, at_least: int, b: int) -> int:
    """The basis size of the next Rayleigh–Ritz check: where the kept Ritz count ``q`` (at size ``m``;
    ``last``: the previous check's ``(m, q)``) reaches ``at_least`` on the line through the last two
    checks, at least a block and at most 25 % further (6 % without two checks to extrapolate from)."""
    step = 0.06 * m
    if last is not None and q < at_least and q > last[1]:
        step = (at_least - q) * (m - last[0]) / (q - last[1])
    return int(m + min(max(step, b), 0.25 * m))


def _count_above(H, m: int, band: int, mu: float) -> int | None:
    """How many eigenvalues of the band of the leading ``m × m`` of ``H`` (upper triangle stored, ``band``
    diagonals beside the main one) exceed ``mu``, by Sylvester's law of inertia, or None if it failed.

    In blocks of ``band`` rows the band is block tridiagonal, ``H − μI = L D Lᵀ`` with block diagonal
    ``D``: ``D₁ = A₁ − μI``, ``Dⱼ = Aⱼ − μI − Cⱼ₋₁ᵀ Dⱼ₋₁⁻¹ Cⱼ₋₁`` (``Cⱼ₋₁``: the block above ``Aⱼ``), and
    ``H − μI`` has as many positive eigenvalues as the ``Dⱼ`` together (Haynsworth). ``Dⱼ = U diag(w) Uᵀ``
    (``eigh`` of ``band × band``); a pivot ``|w| < 1e-15·‖H‖`` is moved to that size, as in a Sturm
    count. ``O(m band²)`` flops (heat_3d n=24: ~0.03 s against 0.6 s for the Ritz values themselves)."""
    scale = float(np.abs(np.diagonal(H)[:m]).max()) or 1.0
    count, X, prev = 0, None, None
    for s in range(0, m, band):
        e = min(s + band, m)
        D = np.triu(H[s:e, s:e]) + np.triu(H[s:e, s:e], 1).T - mu * np.eye(e - s)
        if X is not None:
            D -= H[prev:s, s:e].T @ X
        w, U = la.eigh(D, check_finite=False)
        if not np.all(np.isfinite(w)):
            return None
        count += int((w > 0).sum())
        w = np.where(np.abs(w) < 1e-15 * scale, np.where(w < 0, -1e-15, 1e-15) * scale, w)
        if e < m:
            X = U @ ((U.T @ H[s:e, e:min(e + band, m)]) / w[:, None])
        prev = s
    return count


def _kept_count(H, m: int, band: int, sigma: float, log_gain, log_tol: float) -> int | None:
    """How many Ritz values of the band of ``H`` are kept (:func:`_cut`, :func:`_count_above`); ``μ_top``
    from the leading ``4·band`` rows (the largest Ritz value only grows with the basis: interlacing)."""
    t = min(m, 4 * band)
    mu_top = la.eigvalsh(H[:t, :t], lower=False, subset_by_index=[t - 1, t - 1], check_finite=False)[0]
    if not mu_top > 0:
        return None
    mu_c = _cut(log_gain, log_tol, sigma, mu_top)
    return m if mu_c == -np.inf else _count_above(H, m, band, mu_c)


def _cut(log_gain, log_tol: float, sigma: float, mu_top: float) -> float:
    """``μ_c``: Ritz values ``μ > μ_c`` are kept (``log_gain(σ + 1/μ) ≥ log_gain(σ + 1/μ_top) + log_tol``),
    by bisection in ``log μ`` on ``(1e-16 μ_top, μ_top]``, assuming the gain falls as ``λ = σ + 1/μ``
    grows (heat: the damped branch); ``-inf`` if even ``1e-16 μ_top`` is kept (Crank–Nicolson, whose
    ``|r| → 1`` far beyond any mesh's ``λ_max``: then every check reads the band's Ritz values, as
    before). Only the check schedule relies on it: the kept modes come from the Ritz values themselves."""
    top = log_gain(np.array([sigma + 1.0 / mu_top]))[0] + log_tol

    def kept(log_mu):
        return log_gain(np.array([sigma + np.exp(-log_mu)]))[0] >= top

    lo, hi = np.log(mu_top) + np.log(1e-16), np.log(mu_top)
    if kept(lo):
        return -np.inf
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if kept(mid) else (mid, hi)
    return float(np.exp(lo))


def _band_values(H, m: int, band: int) -> np.ndarray:
    """Eigenvalues (ascending) of the leading ``m × m`` of ``H`` (upper triangle stored) within ``band``
    diagonals of the main one: a banded reduction (LAPACK ``?sbevd``), ``O(m² band)`` flops instead of
    the dense ``4m³/3``. Entries beyond the band are reorthogonalization coefficients at the rounding
    level: leaving them out moves the Ritz values by about their norm (``~1e-13·max μ``), which only
    decides whether to look at the vectors; the vectors come from the whole ``H``."""
    band = min(band, m - 1)
    bands = np.zeros((band + 1, m))
    for d in range(band + 1):
        bands[band - d, d:] = np.diagonal(H, d)[:m - d]
    return la.eig_banded(bands, eigvals_only=True, check_finite=False)


def _ritz(H, basis, B, sigma, log_gain, log_tol, max_fraction, at_least, eps, band):
    """Rayleigh–Ritz on the basis so far: ``((λ, vectors), q)``, the kept modes once they have converged
    (the residual ``‖B Yₗₐₛₜ‖`` of each, weighted by its gain, below ``eps``), else ``(None, q)``; ``q``:
    how many Ritz values are kept; :class:`TooManyModes` past ``max_fraction`` of ``N``."""
    N, m = basis.Q.shape[0], basis.m
    # first how many Ritz values are kept, by inertia (:func:`_count_above`, the largest Ritz value from the
    # leading blocks, converged long since): most checks end there (too few kept); then the Ritz values
    # from H's band (:func:`_band_values`), then the kept vectors when those pass
    q = _kept_count(H, m, band, sigma, log_gain, log_tol) if band < m else None
    if q is not None and q < min(at_least, N) and q <= max_fraction * N:
        return None, q
    mu = _band_values(H[:m, :m], m, band)[::-1]
    lam = sigma + 1.0 / mu
    lg = log_gain(lam)
    kept = lg >= lg.max() + log_tol
    if kept.sum() > max_fraction * N:
        raise TooManyModes(f"the modal backend would need more than {kept.sum()} of {N} modes "
                           f"(> {max_fraction:.0%}); use backend='steps'")
    q = int(kept.sum())
    if q >= min(at_least, N) and not kept[-1]:
        def weight(mu):  # each mode's gain relative to the largest
            return np.exp(log_gain(sigma + 1.0 / mu) - lg.max())

        for lock in ((LOCK_AT, 0.0) if LOCK_AT and m > 4 * band else (0.0,)):
            mq, Y, res = _rayleigh_ritz(H, m, B, q, weight, log_tol, eps, int(lock * m) // band * band)
            if np.all(weight(mq) * res / mq <= eps):
                return (sigma + 1.0 / mq, basis.Q[:, :m] @ Y), q
    return None, q


#: the fraction of the basis whose Ritz pairs are locked in the final Rayleigh–Ritz (:func:`_rayleigh_ritz`)
#: and how far below ``eps`` a locked pair's weighted coupling must be
LOCK_AT, LOCK_MARGIN = 0.6, 0.01


def _rayleigh_ritz(H, m: int, B, q: int, weight, log_tol: float, eps: float, m1: int = 0):
    """The ``q`` largest Ritz pairs of the leading ``m × m`` of ``H`` (upper triangle stored):
    ``(μ, Y, res)``, ``μ`` descending, ``res`` the residual norms ``‖S Q y − μ Q y‖_M``.

    ``m1 = 0``: all of ``H`` by divide and conquer (``eigh``, ``evd``; on heat_3d n=24's ``H``, 4 032 wide,
    9.6 s against 15 s for the kept ones by MRRR or inverse iteration, slowed by the clusters of
    converged Ritz values); ``res = ‖B yₗₐₛₜ‖`` (``S Q = Q H + V B Eᵀ``). ``m1 > 0``: **locking** — the
    leading ``H₁₁ = Y₁ Θ Y₁ᵀ`` first (``m1 × m1``, a fraction of the cost); a kept Ritz pair of ``H₁₁`` whose
    coupling ``eᵢ = (Y₁ᵀH₁₂)ᵢ`` to the rest, weighted by its gain, is already below ``eps·μᵢ`` is set aside
    (the set ``L``); the others enter ``G = [[Θ_R, Y_RᵀH₁₂], [·, H₂₂]]``, ``m − |L|`` wide. Dropping the
    couplings ``E_L`` changes ``H`` by rows of norm ``‖eᵢ‖``, so the residuals stay exact:
    ``res = ‖eᵢ‖`` for a locked pair, ``(‖E_L g₂‖² + ‖B yₗₐₛₜ‖²)^{1/2}`` for an eigenvector ``g = (g_R, g₂)``
    of ``G`` (``y = (Y_R g_R, g₂)``); the caller checks them as it checks the plain ones and falls back
    to ``m1 = 0`` if one fails. heat_3d n=24 (``m`` 3 584, ``m1`` 2 176): about 1 000 locked."""
    b = B.shape[0]
    if m1 <= 0 or m1 > m - b:
        mq, Y = la.eigh(H[:m, :m], lower=False, driver="evd", check_finite=False)
        mq, Y = mq[::-1][:q], Y[:, ::-1][:, :q]  # largest μ first: the kept modes, lowest λ first
        return mq, Y, np.linalg.norm(B @ Y[-b:], axis=0)
    theta, Y1 = la.eigh(H[:m1, :m1], lower=False, driver="evd", check_finite=False)
    E = Y1.T @ H[:m1, m1:m]  # Y₁ᵀH₁₂: its last block's band, and rounding-level reorthogonalization terms
    e = np.linalg.norm(E, axis=1)
    w = weight(theta)
    tight = LOCK_MARGIN * eps  # the caller's check of the residuals below must not fail
    L = (w >= np.exp(log_tol)) & (w * e / theta <= tight)  # converged for its own weight
    rest = w[(w >= np.exp(log_tol)) & ~L]  # the kept ones still moving: dropping eᵢ moves them by ~‖eᵢ‖
    L &= e / theta <= tight / (rest.max() if len(rest) else 1.0)
    R, r = ~L, int((~L).sum())
    G = np.zeros((m - m1 + r,) * 2)
    G[np.arange(r), np.arange(r)] = theta[R]
    G[:r, r:], G[r:, r:] = E[R], H[m1:m, m1:m]
    g_mu, g = la.eigh(G, lower=False, driver="evd", check_finite=False)
    mu = np.concatenate([theta[L], g_mu])
    top = np.argsort(-mu, kind="stable")[:q]
    locked, free = top[top < L.sum()], top[top >= L.sum()] - L.sum()
    Y = np.zeros((m, q))
    Y[:m1, :len(locked)] = Y1[:, np.flatnonzero(L)[locked]]
    Y[:m1, len(locked):] = Y1[:, R] @ g[:r, free]
    Y[m1:, len(locked):] = g[r:, free]
    res = np.concatenate([e[np.flatnonzero(L)[locked]],
                          np.hypot(np.linalg.norm(E[L] @ g[r:, free], axis=0),
                                   np.linalg.norm(B @ g[-b:, free], axis=0))])
    order = np.argsort(-np.concatenate([mu[top[top < L.sum()]], g_mu[free]]), kind="stable")
    return np.concatenate([mu[top[top < L.sum()]], g_mu[free]])[order], Y[:, order], res[order]


def largest_eigenvalue(M, K) -> float:
    """``λ_max`` of ``K φ = λ M φ`` (relative accuracy ~1e-8)."""
    if M.shape[0] <= DENSE_MAX:
        top = [M.shape[0] - 1] * 2
        return float(la.eigh(K.toarray(), M.toarray(), eigvals_only=True, subset_by_index=top)[0])
    return float(sla.eigsh(sp.csc_matrix(K), 1, sp.csc_matrix(M), which="LA", tol=1e-8)[0][0])


def count_below(M, K, lam: float) -> int:
    """How many eigenvalues of ``K φ = λ M φ`` lie below ``lam``, by Sylvester's law of inertia:
    the negative pivots of ``K − lam·M = P L D Lᵀ Pᵀ``, from one sparse LU with diagonal pivoting
    in symmetric mode (SuperLU; ``U = D Lᵀ``, so the signs of ``diag U`` are the inertia). One
    factorization, about the cost of one time step's; where Weyl's law over-counts a coarse mesh
    (heat_3d n=24: 3 963 by Weyl, 1 820 modes kept) it sizes the eigensolve and the cost model
    right. A pivot that is exactly zero (``lam`` an eigenvalue) counts as non-negative."""
    A = sp.csc_matrix(K - lam * M)
    lu = sla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
    return int((lu.U.diagonal() < 0).sum())
