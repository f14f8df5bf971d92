"""Linear references: the MMSE estimator against the mean and the best-α Tikhonov reconstruction."""

import numpy as np
from exact import load

from pdeinv.training.references import best_filter, dense_operator, mmse, tikhonov_best, tikhonov_path


def _data(p, n_train):
    x, _ = p.sample(n_train, 1)
    xt, yt = p.sample(32, 2)
    return x, xt, yt


def test_mmse_beats_best_alpha_tikhonov_noise_free():
    """With a prior learnt from 512 samples, the MMSE fills in modes the heat equation killed."""
    p = load("heat_2d", n=8, steps=10, kappa=0.05)
    x, xt, yt = _data(p, 512)
    est, info = mmse(p, x)
    mm = np.mean(p.relative_error(est(yt), xt))
    tk = tikhonov_best(p, yt, xt)
    assert info["sigma2_rule"].startswith("tiny")
    assert mm <= tk["x_err"] and mm < 0.1


def test_mmse_on_its_training_data_beats_w_zero():
    """W fitted on (X, P X) reconstructs X better than W = 0 (the prior mean μ)."""
    p = load("heat_1d", n=16, steps=10, noise=0.05)
    x, y = p.sample(64, 1)
    est, info = mmse(p, x)
    assert info["sigma2_rule"] == "noise"
    mean_only = np.tile(x.mean(0), (len(x), 1))
    assert np.mean(p.relative_error(est(y), x)) < 0.5 * np.mean(p.relative_error(mean_only, x))


def test_tikhonov_path_matches_a_direct_solve():
    """x̂_α from the SVD equals the solution of (PᵀMP + αM) x = PᵀM y."""
    p = load("heat_1d", n=16, steps=10)
    P = dense_operator(p)
    M = p.disc.M.toarray()
    solve, smax = tikhonov_path(p, P)
    _, y = p.sample(3, 0)
    alpha = 1e-4 * smax**2
    direct = np.linalg.solve(P.T @ M @ P + alpha * M, P.T @ M @ y.T).T
    np.testing.assert_allclose(solve(y, alpha), direct, rtol=1e-8, atol=1e-10)


def test_best_filter_bounds_tikhonov_and_recovers_it():
    """Every Tikhonov filter is a spectral filter: on its own training pairs the fitted best filter
    is at least as good as the best α; and fed Tikhonov reconstructions as "truth" it returns
    exactly the Tikhonov filter s²/(s²+α)."""
    p = load("heat_1d", n=16, steps=10, noise=0.02)
    x, y = p.sample(256, 1)
    P = dense_operator(p)
    best = best_filter(p, x, y, x, y, P=P)
    assert best["x_err"] <= tikhonov_best(p, y, x, P=P)["x_err"] + 1e-12
    solve, smax = tikhonov_path(p, P)
    alpha = 1e-3 * smax**2
    fitted = best_filter(p, solve(y, alpha), y, x, y, P=P)["filter"]
    s = np.linalg.svd(np.linalg.cholesky(p.disc.M.toarray()).T @ P @ np.linalg.inv(
        np.linalg.cholesky(p.disc.M.toarray())).T, compute_uv=False)
    np.testing.assert_allclose(fitted, s**2 / (s**2 + alpha), rtol=1e-8, atol=1e-10)
