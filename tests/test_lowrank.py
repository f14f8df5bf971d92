"""The SVD from forward and adjoint products (physics/lowrank.py) against stepping and the dense SVD."""

import numpy as np
import pytest

import pdeinv
from pdeinv.physics.backends import compiled
from pdeinv.physics.backends.lowrank import RankTooHigh, svd_from_products


@pytest.fixture(autouse=True)
def _uncached(monkeypatch):
    monkeypatch.setenv("PDEINV_NO_CACHE", "1")


def _maps(name, **kw):
    """(forward, adjoint, n_in, n_out, M, M_out) of a scene's stepping operator."""
    op = pdeinv.load_problem(name, backend="steps", **kw).operator
    run = op.backend.run if hasattr(op.backend, "run") else op
    M_out = run.mass if run.output_space == "field" else None
    return run._step_forward, run._step_adjoint, op.n_in, op.n_out, run.mass, M_out


CASES = {"records (Euclidean out)": ("heat_sensors_2d", dict(n=16, steps=20, record_every=4, sensors=16,
                                                             kappa=0.1)),
         "field (M out, non-symmetric)": ("advection_diffusion_2d", dict(n=16, steps=20, kappa=0.05))}


@pytest.mark.parametrize("case", CASES)
def test_products_give_the_dense_svd_and_the_stepping_operator(case):
    name, kw = CASES[case]
    f, a, n, m, M, Mo = _maps(name, **kw)
    arrays = svd_from_products(f, a, n, m, M, Mo, block=8)
    svd = compiled.SVD.restore(arrays, Mo)
    dense = compiled.SVD(compiled.matrix(f, n, m), M, Mo)
    assert svd.k == dense.k < min(n, m)  # numerically low rank, same truncation
    assert np.max(np.abs(svd.g - dense.g) / dense.g[0]) <= 1e-12
    rng = np.random.default_rng(0)
    X, R = rng.standard_normal((3, n)), rng.standard_normal((3, m))
    for got, want in ((svd.forward(X), f(X)), (svd.adjoint(R), a(R))):
        assert np.linalg.norm(got - want) / np.linalg.norm(want) <= 1e-10
    assert abs(np.sum(svd.forward(X) * R) - np.sum(X * svd.adjoint(R))) <= 1e-12 * np.linalg.norm(X) \
        * np.linalg.norm(R) * svd.g[0]
    # the bases are orthonormal in the problem's norms
    Mo_ = np.eye(m) if Mo is None else Mo.toarray()
    assert np.abs(svd.out.T @ Mo_ @ svd.out - np.eye(svd.k)).max() <= 1e-10
    assert np.abs(svd.synth.T @ M @ svd.synth - np.eye(svd.k)).max() <= 1e-10


def test_a_full_rank_operator_is_refused_and_build_falls_back_to_the_dense_matrix():
    f, a, n, m, M, Mo = _maps("heat_2d", n=8, kappa=1e-4, steps=5)  # barely damped: rank N
    with pytest.raises(RankTooHigh, match="more than 16"):
        svd_from_products(f, a, n, m, M, Mo, max_rank=16, block=8)
    built = compiled.build("svd", f, n, m, M, Mo, adjoint=a)
    assert built.k == n
    X = np.random.default_rng(1).standard_normal((2, n))
    assert np.linalg.norm(built.forward(X) - f(X)) / np.linalg.norm(f(X)) <= 1e-10


def test_over_the_dense_budget_the_svd_comes_from_products(monkeypatch):
    f, a, n, m, M, Mo = _maps("advection_diffusion_2d", n=16, steps=20, kappa=0.05)
    dense_gb = compiled.SVD.nbytes(n, m) / 1e9
    monkeypatch.setenv("PDEINV_DENSE_BUDGET_GB", str(dense_gb / 2))  # the products need far less
    monkeypatch.setattr(compiled, "matrix", lambda *a, **k: pytest.fail("built the dense matrix"))
    built = compiled.build("svd", f, n, m, M, Mo, adjoint=a)
    X = np.random.default_rng(2).standard_normal((2, n))
    assert built.k < n and np.linalg.norm(built.forward(X) - f(X)) / np.linalg.norm(f(X)) <= 1e-10


@pytest.mark.parametrize("rtol", [0.0, 1.0, -1e-3])
def test_rtol_outside_zero_one_is_refused(rtol):
    with pytest.raises(ValueError, match=f"rtol={rtol!r} is not allowed"):
        svd_from_products(lambda X: X, lambda R: R, 4, 4, rtol=rtol)
