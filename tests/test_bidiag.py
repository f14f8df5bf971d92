"""Matrix-free Tikhonov for every α (pdeinv.inverse.bidiag) against the dense SVD path of the references."""

import numpy as np
import pytest

import pdeinv
from pdeinv.inverse.bidiag import bidiagonalize
from pdeinv.training import references as R

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.parametrize("name, settings", [("heat_2d", dict(n=8)), ("wave_2d", dict(n=8)),
                                            ("heat_sensors_2d", dict(n=12))])
def test_the_full_space_gives_the_dense_tikhonov_solution_for_every_alpha(name, settings):
    """With as many iterations as unknowns the space is exhausted: x_α equals the SVD path's (M-weighted
    penalty, M_out on field observations, the identity on sensors) to rounding, for α across ten decades."""
    p = pdeinv.load_problem(name, **settings)
    x, y = p.sample(4, seed=3)
    y = y + 0.01 * np.abs(y).max() * np.random.default_rng(1).standard_normal(y.shape)
    solve, smax = R.tikhonov_path(p)
    space = bidiagonalize(p.operator, y, p.disc.M, iterations=p.N)
    assert space.s_max == pytest.approx(smax, rel=1e-10)
    for a in (1e-1, 1e-4, 1e-7, 1e-10):
        dense = solve(y, a * smax**2)
        err = np.abs(space.solve(a * smax**2) - dense).max() / np.abs(dense).max()
        assert err < 1e-8 * max(1.0, 1e-9 / a), (name, a, err)


def test_the_basis_is_mass_orthonormal_and_truncation_converges():
    p = pdeinv.load_problem("wave_2d", n=10)
    _, y = p.sample(3, seed=5)
    space = bidiagonalize(p.operator, y, p.disc.M, iterations=60)
    M = p.disc.M
    for b in range(3):
        Vb = space.V[:, b, :]
        assert np.abs(Vb @ (M @ Vb.T) - np.eye(60)).max() < 1e-10
    a = 1e-2 * space.s_max**2  # the space resolves what α keeps well before it is exhausted (81 unknowns)
    full = space.solve(a)
    changes = [np.linalg.norm(space.truncated(k).solve(a) - full) / np.linalg.norm(full)
               for k in (5, 10, 20, 40)]
    assert all(np.diff(changes) < 0) and changes[-1] < 1e-4 < 0.05 < changes[0]


def test_the_krylov_reference_equals_the_dense_one_on_a_small_scene():
    p = pdeinv.load_problem("wave_2d", n=12, noise=0.01)
    x, y = p.sample(8, seed=2)
    dense = R.tikhonov_best(p, y, x)
    krylov = R.tikhonov_best_krylov(p, y, x, iterations=p.N)
    assert krylov["alpha_rel"] == dense["alpha_rel"]
    assert krylov["x_err"] == pytest.approx(dense["x_err"], rel=1e-8)
    assert krylov["converged"] < 1e-3


def test_bad_input_is_named():
    p = pdeinv.load_problem("heat_2d", n=6)
    with pytest.raises(ValueError, match="row is zero"):
        bidiagonalize(p.operator, np.zeros((2, p.operator.n_out)), p.disc.M)
    with pytest.raises(ValueError, match="iterations"):
        bidiagonalize(p.operator, np.ones((1, p.operator.n_out)), p.disc.M, iterations=0)


def test_the_krylov_reference_counts_only_converged_alphas():
    """A small space resolves large α only: smaller ones are left out of the choice (a truncated space
    regularizes by itself) and reported apart; a space in which no α converged is refused."""
    p = pdeinv.load_problem("wave_2d", n=12, noise=0.01)
    x, y = p.sample(6, seed=4)
    r = R.tikhonov_best_krylov(p, y, x, iterations=20)
    small = [c for a, (_, c) in r["sweep"].items() if float(a) <= 1e-8]
    assert r["converged"] < 1e-2 and min(small) >= 1e-2 and r["unconverged_x_err"] is not None
    with pytest.raises(ValueError, match="no α of the grid converged"):
        R.tikhonov_best_krylov(p, y, x, grid=(1e-10,), iterations=4)
