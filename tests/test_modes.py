"""The large-mesh eigen build: a block Krylov eigensolve sized by Weyl's law, the dense eigh's modes."""

import numpy as np
import pytest

import pdeinv
from pdeinv.errors import TooManyModes
from pdeinv.fem.forms import discretize
from pdeinv.physics import Heat, Modal, Stepping
from pdeinv.physics.backends import modes


def _heat(n, **kw):
    d = discretize(pdeinv.fem.mesh.unit_square(n))
    return Heat(d.M, d.K, backend="steps", measure=d.measure, dim=d.dim, **kw)


def _log_gain(heat):
    return lambda lam: heat.steps * np.log(np.maximum(np.abs(heat.amplification(lam) ** (1 / heat.steps)),
                                                      1e-300))


@pytest.mark.parametrize("scheme", ["be", "cn"])
def test_block_krylov_gives_the_dense_modes_and_the_stepping_operator(monkeypatch, scheme):
    """~110 of 1521 modes kept; the block Krylov path (large meshes) against the dense eigh."""
    heat = _heat(40, scheme=scheme, kappa=0.02)
    monkeypatch.setenv("PDEINV_NO_CACHE", "1")  # compute both
    monkeypatch.setattr(modes, "DENSE_MAX", 2000)
    dense = Modal(heat)
    monkeypatch.setattr(modes, "DENSE_MAX", 10)
    sparse = Modal(heat)
    assert dense.k > 64
    # the Krylov space may not have found the last modes at the cut-off: they carry ≈ tol
    assert dense.k - 3 <= sparse.k <= dense.k
    rel = np.abs(sparse.lam - dense.lam[:sparse.k]) / dense.lam[:sparse.k]
    weight = np.abs(sparse.g / sparse.g[0])
    assert rel[weight >= 1e-6].max() <= 1e-10 and rel.max() <= 1e-5  # modes near the cut carry ≈ tol
    assert np.abs(sparse.Phi.T @ heat.M @ sparse.Phi - np.eye(sparse.k)).max() <= 1e-12
    x = np.random.default_rng(0).standard_normal((3, heat.n_in))
    ys = Stepping(heat).forward(x)
    for op in (dense, sparse):
        assert np.linalg.norm(op.forward(x) - ys) / np.linalg.norm(ys) <= 1e-10


def test_the_stopping_rule_weighs_each_mode_by_its_gain(monkeypatch):
    """Looser ``eps`` → a smaller Krylov space and a less accurate operator, both measured (from a plain
    random start: the powered one has every mode converged to 1e-11 at the first check here)."""
    monkeypatch.setattr(modes, "START_POWERS", 0)
    heat = _heat(40, kappa=0.02)  # 1521 unknowns
    x = np.random.default_rng(1).standard_normal((2, heat.n_in))
    ys = Stepping(heat).forward(x)
    log_gain = _log_gain(heat)
    errs = []
    for eps in (1e-4, 1e-12):
        lam, Phi = modes.lowest_modes(heat.M, heat.K, log_gain, np.log(heat.tol), k=100, eps=eps, dense_max=0)
        g = heat.amplification(lam)
        y = ((x @ heat.M @ Phi) * g) @ Phi.T
        errs.append(np.linalg.norm(y - ys) / np.linalg.norm(ys))
    assert errs[1] <= 1e-10 < 1e-3 * errs[0], errs  # eps=1e-4 stops earlier and is visibly less exact


def test_too_many_modes_is_refused_and_k_checked():
    d = discretize(pdeinv.fem.mesh.unit_square(16))
    flat = lambda lam: np.zeros_like(lam)  # noqa: E731  every mode matters: more than half of N
    with pytest.raises(TooManyModes, match="more than"):
        modes.lowest_modes(d.M, d.K, flat, np.log(1e-14), k=30, dense_max=0)
    with pytest.raises(ValueError, match="k=0"):
        modes.lowest_modes(d.M, d.K, flat, np.log(1e-14), k=0, dense_max=0)


def test_a_rank_deficient_block_keeps_its_range():
    """``W = V B`` exactly when ``W`` has dependent columns; the filled-in columns are M-orthonormal."""
    d = discretize(pdeinv.fem.mesh.unit_square(12))
    rng = np.random.default_rng(0)
    basis = modes._Basis(d.M, 8)
    basis.append(modes._cholqr(rng.standard_normal((d.N, 4)), d.M)[0])
    W = rng.standard_normal((d.N, 2)) @ rng.standard_normal((2, 4))  # rank 2 of 4
    basis.orthogonalize(W)
    V, B = modes._rank_revealing(W, d.M, basis, rng)
    assert np.allclose(V @ B, W, atol=1e-12)
    assert np.abs(V.T @ d.M @ V - np.eye(4)).max() <= 1e-12
    assert np.abs(basis.Q[:, :basis.m].T @ (d.M @ V)).max() <= 1e-12


def test_count_below_is_the_exact_eigenvalue_count_and_weyl_overcounts_3d():
    """Sylvester's inertia of ``K − λM`` (one sparse LU) counts the discrete eigenvalues below ``λ``
    exactly; on a coarse 3-D mesh Weyl's continuum count is 2-3x more, so the heat operator sizes its
    modal eigensolve by the inertia count beyond ``DENSE_MAX``."""
    import scipy.linalg as la

    from pdeinv.physics.backends.modal import weyl_count

    d = discretize(pdeinv.fem.mesh.unit_cube(10))  # 729 unknowns
    lam = la.eigh(d.K.toarray(), d.M.toarray(), eigvals_only=True)
    for cut in (50.0, 700.0, 3800.0):
        assert modes.count_below(d.M, d.K, cut) == int((lam < cut).sum())
    heat = Heat(d.M, d.K, backend="steps", measure=d.measure, dim=3)
    assert weyl_count(heat, 3800.0) > 2 * int((lam < 3800.0).sum())


def test_count_modes_uses_the_inertia_count_beyond_the_dense_size(monkeypatch):
    d = discretize(pdeinv.fem.mesh.unit_cube(8))
    heat = Heat(d.M, d.K, backend="steps", measure=d.measure, dim=3, kappa=0.01)
    weyl = heat.count_modes(38.0)
    monkeypatch.setattr(modes, "DENSE_MAX", 10)
    lam = np.linalg.eigvalsh(np.linalg.solve(np.linalg.cholesky(d.M.toarray()),
                                             np.linalg.solve(np.linalg.cholesky(d.M.toarray()),
                                                             heat.scheme.L.toarray()).T))
    exact = heat.count_modes(38.0)
    assert exact == int((lam < 38.0).sum()) < weyl


def test_route_takes_the_dense_eigh_where_the_krylov_basis_would_be_most_of_the_space():
    """Dense up to DENSE_MAX; between it and DENSE_EIGH_MAX by cost; no Krylov for k > N/2."""
    assert modes.route(1000, 900) == "dense"
    assert modes.route(3969, 300) == "krylov"  # heat_2d n=64: a few hundred of 3 969
    assert modes.route(3375, 1571) == "krylov"  # heat_3d n=16: 5.8 s against 6.4 s for the dense eigh
    assert modes.route(3375, 1700) == "dense"  # k > N/2: the Krylov basis would be the whole space
    assert modes.krylov_flops(12167, 2075) < 0.1 * 9 * 12167**3  # heat_3d n=24: 20 s; dense ~300 s
    assert modes.route(modes.DENSE_EIGH_MAX + 1, modes.DENSE_EIGH_MAX) is None
    assert modes.route(12167, 2000) == "krylov"


def test_the_geometric_checks_give_the_same_modes_on_a_3d_mesh(monkeypatch):
    """The block Krylov method (checks at geometrically growing bases, started from the exact count)
    against the dense eigh on a 3-D mesh where Weyl over-counts: the same operator to 1e-10."""
    d = discretize(pdeinv.fem.mesh.unit_cube(12))  # 1331 unknowns
    heat = Heat(d.M, d.K, backend="steps", measure=d.measure, dim=3, kappa=0.01, tol=1e-8)
    monkeypatch.setenv("PDEINV_NO_CACHE", "1")
    dense = Modal(heat)
    monkeypatch.setattr(modes, "DENSE_MAX", 10)
    heat._counts = {}
    sparse = Modal(heat)
    assert dense.k - 3 <= sparse.k <= dense.k and sparse.k > 100
    x = np.random.default_rng(2).standard_normal((3, heat.n_in))
    ys = dense.forward(x)
    assert np.linalg.norm(sparse.forward(x) - ys) / np.linalg.norm(ys) <= 1e-10


def test_band_values_are_the_ritz_values_of_the_banded_block_lanczos_matrix():
    """``_band_values`` reads the upper band of ``H`` (the block tridiagonal of block Lanczos, upper
    triangle stored): the eigenvalues of the dense symmetric matrix to rounding; what lies off the band
    (reorthogonalization coefficients at the rounding level) moves them by no more than its norm."""
    rng = np.random.default_rng(3)
    m, band = 90, 6
    A = rng.standard_normal((m, m))
    A = np.triu(np.tril(A + A.T, band), -band)
    off = 1e-15 * np.triu(rng.standard_normal((m, m)), band + 1)
    H = np.triu(A) + off  # only the upper triangle is read
    got = modes._band_values(H, m, band)
    assert np.abs(got - np.linalg.eigvalsh(A)).max() <= 1e-12 * np.abs(got).max()
    assert np.abs(modes._band_values(H, m, band - 1) - got).max() > 1e-3  # the band width matters


def test_one_full_pass_after_the_local_one_leaves_the_block_orthogonal_to_the_basis():
    """``orthogonalize(W, local)``: against the last ``local`` columns, then once against all; the block
    is M-orthogonal to the whole basis to rounding and ``W = Q C + W_after``."""
    d = discretize(pdeinv.fem.mesh.unit_square(20))
    rng = np.random.default_rng(4)
    basis = modes._Basis(d.M, 64)
    for _ in range(4):
        V = rng.standard_normal((d.N, 8))
        basis.orthogonalize(V)
        V = modes._cholqr(V, d.M)[0]
        basis.append(V)
    W0 = basis.Q[:, 16:32] @ rng.standard_normal((16, 8)) + 1e-6 * rng.standard_normal((d.N, 8))
    W = W0.copy()
    C = basis.orthogonalize(W, local=16)
    assert np.abs(basis.Q[:, :basis.m].T @ (d.M @ W)).max() <= 1e-15 * np.abs(W0).max() * d.N
    assert np.allclose(basis.Q[:, :basis.m] @ C + W, W0, atol=1e-13)
    assert np.abs(C[:16]).max() < 1e-5 < np.abs(C[16:]).max()  # the local pass took the large part


def test_the_next_check_is_extrapolated_from_the_ritz_counts():
    assert modes._next_check(3000, 1700, (2800, 1600), 1877, 64) == 3354  # (177 / 100) * 200 = 354
    assert modes._next_check(3000, 1700, None, 1877, 64) == 3180  # 6 % without two checks
    assert modes._next_check(3000, 1876, (2900, 1800), 1877, 64) == 3064  # at least a block
    assert modes._next_check(3000, 1000, (2990, 999), 1877, 64) == 3750  # at most 25 %


def _block_tridiagonal(rng, m, band):
    A = rng.standard_normal((m, m))
    return np.triu(np.tril(A + A.T, band), -band)


@pytest.mark.parametrize("m,band", [(90, 6), (97, 8), (40, 40)])
def test_the_inertia_count_is_the_number_of_eigenvalues_above(m, band):
    """``_count_above``: the block LDLᵀ (Haynsworth) count of the band's eigenvalues above ``μ`` equals the
    dense count, also at ``μ`` an eigenvalue of the matrix or of a leading block (a zero pivot)."""
    rng = np.random.default_rng(5)
    A = _block_tridiagonal(rng, m, band)
    H = np.triu(A) + 1e-15 * np.triu(rng.standard_normal((m, m)), band + 1)  # upper triangle stored
    lam = np.linalg.eigvalsh(A)
    lead = np.linalg.eigvalsh(A[:band, :band])[:3] if band < m else []  # a zero pivot in D₁
    grid = np.linspace(lam[0] - 1, lam[-1] + 1, 41)
    for mu in np.concatenate([grid, lam[::7] + 1e-9, lead]):
        assert modes._count_above(H, m, band, mu) == int((lam > mu).sum()), mu
    if band < m:  # the partition must hold the band
        assert any(modes._count_above(H, m, band - 1, mu) != int((lam > mu).sum()) for mu in grid)


def test_the_cut_separates_the_kept_ritz_values():
    heat = _heat(12, kappa=0.02)
    log_gain, log_tol, sigma = _log_gain(heat), np.log(heat.tol), -1e-6
    mu = 1.0 / np.geomspace(1.0, 1e5, 400)
    mu_c = modes._cut(log_gain, log_tol, sigma, mu[0])
    kept = log_gain(sigma + 1 / mu) >= log_gain(np.array([sigma + 1 / mu[0]]))[0] + log_tol
    assert 0 < kept.sum() < len(mu) and np.array_equal(kept, mu > mu_c)
    flat = lambda lam: np.zeros_like(lam)  # noqa: E731
    assert modes._cut(flat, log_tol, sigma, 1.0) == -np.inf


def test_the_powered_start_and_the_inertia_checks_give_the_same_modes_with_fewer_vectors(monkeypatch):
    """``START_POWERS`` solves on the random start block (:func:`modes._start_block`) and the checks that
    stop at the inertia count change the basis size only: the same eigenpairs as a plain start checked on
    the Ritz values, to 1e-10 where the gain is ≥ 1e-6 of the largest, and the same operator."""
    heat = _heat(48, kappa=0.02)  # 2209 unknowns
    log_gain, log_tol = _log_gain(heat), np.log(heat.tol)
    from scipy.optimize import brentq

    cut = brentq(lambda lam: log_gain(np.array([lam]))[0] - log_gain(np.zeros(1))[0] - log_tol, 0, 1e6)
    at_least = modes.count_below(heat.M, heat.K, cut)
    sizes = []
    original = modes._ritz

    def ritz(H, basis, *a):
        sizes.append(basis.m)
        return original(H, basis, *a)

    monkeypatch.setattr(modes, "_ritz", ritz)
    new = modes.lowest_modes(heat.M, heat.K, log_gain, log_tol, k=120, dense_max=0, at_least=at_least)
    new_m = sizes[-1]
    monkeypatch.setattr(modes, "START_POWERS", 0)
    monkeypatch.setattr(modes, "_kept_count", lambda *a: None)
    old = modes.lowest_modes(heat.M, heat.K, log_gain, log_tol, k=120, dense_max=0, at_least=at_least)
    assert new_m < sizes[-1] and len(new[0]) >= at_least > 100
    k = min(len(new[0]), len(old[0]))
    w = np.exp(log_gain(new[0][:k]) - log_gain(new[0][:1]))
    assert (np.abs(new[0][:k] - old[0][:k]) / old[0][:k])[w >= 1e-6].max() <= 1e-10
    assert np.abs(new[1].T @ heat.M @ new[1] - np.eye(len(new[0]))).max() <= 1e-12
    x = np.random.default_rng(6).standard_normal((3, heat.n_in))
    ops = [((x @ heat.M @ Phi) * np.exp(log_gain(lam))) @ Phi.T for lam, Phi in (new, old)]
    assert np.linalg.norm(ops[0] - ops[1]) / np.linalg.norm(ops[1]) <= 1e-10


def test_the_powered_start_survives_a_singular_neumann_stiffness():
    """Pure Neumann: ``K`` singular, ``σ`` just below 0, ``μ₁ ≈ 1/|σ|``: the start block's powers stop where
    Cholesky QR fails and the modes are the dense solver's (λ₁ = 0 included)."""
    import scipy.linalg as la

    d = discretize(pdeinv.fem.mesh.unit_square(30), dirichlet=False)
    log_gain = lambda lam: -30 * np.log1p(0.01 * np.maximum(lam, 0))  # noqa: E731  backward Euler
    lam, Phi = modes.lowest_modes(d.M, d.K, log_gain, np.log(1e-10), k=80, dense_max=0)
    dense = la.eigh(d.K.toarray(), d.M.toarray(), eigvals_only=True)
    assert abs(lam[0]) <= 1e-8 and len(lam) >= int((log_gain(dense) >= np.log(1e-10)).sum()) - 3
    # 1e-9: the modes near the cut stop on their gain-weighted residual (1.2e-10 seen with one BLAS thread)
    assert np.abs(lam[1:] - dense[1:len(lam)]).max() / dense[len(lam)] <= 1e-9


def test_locking_gives_the_eigenpairs_of_the_whole_rayleigh_ritz_with_exact_residuals(monkeypatch):
    """``_rayleigh_ritz`` with locking (the leading ``m1`` rows first, converged pairs set aside) against
    the plain ``eigh`` of all of ``H``, on the ``H`` of a real run: the same Ritz values to 1e-10 where the
    gain is ≥ 1e-6 of the largest, the same weighted operator ``Y diag(w) Yᵀ`` to 1e-10, ``Y`` orthonormal;
    and each residual it reports is the true ``(‖H y − μ y‖² + ‖B yₗₐₛₜ‖²)^{1/2}``."""
    heat = _heat(64, kappa=0.01)  # 3969 unknowns
    got = {}
    original = modes._rayleigh_ritz

    def spy(H, m, B, q, weight, log_tol, eps, m1=0):
        got.update(H=H.copy(), m=m, B=B, q=q, weight=weight, log_tol=log_tol, eps=eps, m1=m1)
        return original(H, m, B, q, weight, log_tol, eps, m1)

    monkeypatch.setattr(modes, "_rayleigh_ritz", spy)
    modes.lowest_modes(heat.M, heat.K, _log_gain(heat), np.log(heat.tol), k=200, dense_max=0)
    H, m, B, q, weight = (got[k] for k in ("H", "m", "B", "q", "weight"))
    assert got["m1"] > 0  # the run took the locked path
    plain = original(H, m, B, q, weight, got["log_tol"], got["eps"])
    locked = original(H, m, B, q, weight, got["log_tol"], got["eps"], got["m1"])
    Y = locked[1]
    aside = np.abs(Y[got["m1"]:]).max(axis=0) == 0
    assert aside.sum() >= 10  # pairs set aside at m1
    w = weight(plain[0])
    assert (np.abs(locked[0] - plain[0]) / plain[0])[w >= 1e-6].max() <= 1e-10
    ops = [(Yk * weight(mu)) @ Yk.T for mu, Yk, _ in (plain, locked)]
    assert np.abs(ops[0] - ops[1]).max() <= 1e-10
    assert np.abs(Y.T @ Y - np.eye(q)).max() <= 1e-12
    Hs = np.triu(H[:m, :m]) + np.triu(H[:m, :m], 1).T
    true = np.hypot(np.linalg.norm(Hs @ Y - Y * locked[0], axis=0), np.linalg.norm(B @ Y[-len(B):], axis=0))
    assert np.abs(true - locked[2]).max() <= 1e-13 * locked[0].max()
    assert locked[2][aside].min() > 0  # their dropped couplings, counted in their residuals


def test_a_failed_locking_falls_back_to_the_whole_rayleigh_ritz(monkeypatch):
    """Locking everything converged only to ``1e8·eps`` fails the residual check: the plain ``eigh`` is
    taken instead and gives the same modes as without locking."""
    heat = _heat(64, kappa=0.01)
    args = (heat.M, heat.K, _log_gain(heat), np.log(heat.tol))
    calls = []
    original = modes._rayleigh_ritz
    monkeypatch.setattr(modes, "_rayleigh_ritz", lambda *a: calls.append(a[-1]) or original(*a))
    monkeypatch.setattr(modes, "LOCK_MARGIN", 1e8)
    loose = modes.lowest_modes(*args, k=200, dense_max=0)
    assert calls[0] > 0 and calls[-1] == 0
    monkeypatch.setattr(modes, "LOCK_AT", 0.0)
    plain = modes.lowest_modes(*args, k=200, dense_max=0)
    assert np.array_equal(loose[0], plain[0]) and np.array_equal(loose[1], plain[1])
