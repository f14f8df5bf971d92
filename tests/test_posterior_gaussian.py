"""The linear-Gaussian posterior: low-rank against the dense formula, calibrated on its own prior."""

import numpy as np
import pytest

import pdeinv
from pdeinv.posterior import GaussianPrior, LinearGaussian
from pdeinv.posterior.gaussian import noise_std


def dense_posterior(P, C, m, sigma, y):
    S = P @ C @ P.T + sigma**2 * np.eye(len(P))
    K = np.linalg.solve(S, P @ C).T
    return m + (y - P @ m) @ K.T, C - K @ P @ C


@pytest.fixture(scope="module")
def heat_1d():
    problem = pdeinv.load_problem("heat_1d", prior="grf")
    prior = GaussianPrior.from_draws(problem.sample(4000, seed=1)[0])
    return problem, prior


def test_low_rank_matches_dense(heat_1d):
    """At 1 % noise (cond(P C Pᵀ + σ²I) ≈ 4e5: the dense formula itself is good to ~1e-10)."""
    level = 0.01
    problem, prior = heat_1d
    sigma = noise_std(problem.operator, prior, level)
    post = LinearGaussian(problem.operator, prior, sigma)
    P = problem.operator.forward(np.eye(problem.N)).T
    C = prior.factor @ prior.factor.T
    y = problem.sample(5, seed=2)[1]
    mu, cov = dense_posterior(P, C, prior.mean, sigma, y)
    scale = np.abs(C).max()
    assert np.abs(post.covariance() - cov).max() < 1e-8 * scale
    assert np.abs(post.std**2 - np.diag(cov)).max() < 1e-8 * scale
    assert np.abs(post.mean(y) - mu).max() < 1e-8 * np.abs(mu).max()
    assert post.rank < problem.N  # the smoothing operator sees few directions


def test_randomized_route_matches_exact():
    """The randomized eigensolver (rank ≪ r) agrees with the exact eigendecomposition."""
    problem = pdeinv.load_problem("heat_2d", n=16, prior="grf")
    prior = GaussianPrior.from_draws(problem.sample(600, seed=3)[0])
    sigma = noise_std(problem.operator, prior, 0.01)
    fast = LinearGaussian(problem.operator, prior, sigma)
    P = problem.operator.forward(np.eye(problem.N)).T
    C = prior.factor @ prior.factor.T
    _, cov = dense_posterior(P, C, prior.mean, sigma, np.zeros((1, P.shape[0])))
    assert fast.rank + 10 < prior.factor.shape[1]  # the randomized route was taken
    assert np.abs(fast.covariance() - cov).max() < 1e-8 * np.abs(C).max()


def test_intervals_and_samples_are_calibrated(heat_1d):
    """Fields drawn from the Gaussian prior itself: 90 % intervals cover 90 %, samples have the std."""
    problem, prior = heat_1d
    sigma = noise_std(problem.operator, prior, 0.01)
    post = LinearGaussian(problem.operator, prior, sigma)
    rng = np.random.default_rng(5)
    x = prior.mean + rng.standard_normal((2000, prior.factor.shape[1])) @ prior.factor.T
    y = problem.operator.forward(x) + sigma * rng.standard_normal((2000, problem.operator.n_out))
    lo, hi = post.interval(y, 0.9)
    assert 0.88 < np.mean((lo <= x) & (x <= hi)) < 0.92
    draws = post.sample(y[:3], 4000, seed=6)
    assert draws.shape == (3, 4000, problem.N)
    ratio = draws.std(axis=1) / post.std
    assert np.abs(np.median(ratio) - 1) < 0.03
    assert np.abs(draws.mean(axis=1) - post.mean(y[:3])).max() < 0.1 * post.std.max()


def test_bad_sigma(heat_1d):
    problem, prior = heat_1d
    with pytest.raises(ValueError, match="sigma=0"):
        LinearGaussian(problem.operator, prior, 0.0)


def test_classical_reports_the_gaussian_posterior(tmp_path, capsys):
    """`pdeinv classical` on grf data at 1 % noise: the reference's 90 % intervals cover about 90 %."""
    import json

    from pdeinv.cli import main

    problem = pdeinv.load_problem("heat_1d", prior="grf", noise=0.01)
    x, y = problem.sample(400, seed=11)
    np.savez(tmp_path / "d.npz", x=x, y=y)
    out = tmp_path / "c.json"
    assert main(["classical", "heat_1d", "--set", "prior=grf", "--set", "noise=0.01", "--data",
                 str(tmp_path / "d.npz"), "--out", str(out)]) == 0
    ref = json.loads(out.read_text())["gaussian_posterior"]
    assert 0.86 <= ref["coverage_90"] <= 0.94 and ref["draws"] == 4096 and ref["rank"] < problem.N
    assert ref["x_err"] < 0.3 and ref["std_mean"] > 0
    capsys.readouterr()
