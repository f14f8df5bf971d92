"""AMG-preconditioned CG (pdeinv.fem.solvers.AMGCG) and the automatic choice of solver by mesh dimension."""

import numpy as np
import pytest
import scipy.sparse as sp
from exact import dot_test

from pdeinv.errors import ConvergenceError
from pdeinv.fem import mesh, solvers
from pdeinv.fem.solvers import AMG_CROSSOVER, AMGCG, Cholesky, SuperLU, amg_cg, default_solver, uses_amg
from pdeinv.physics import Heat, Wave

CASES = [(2, 24, "heat"), (2, 24, "wave"), (3, 8, "heat"), (3, 8, "wave")]


def discretization(dim: int, n: int):
    """P1 on the unit square / cube, ``n`` subdivisions per side, Dirichlet boundary (as
    ``benchmarks/scaling.py``)."""
    from pdeinv.fem.forms import discretize

    return discretize({1: mesh.interval, 2: mesh.unit_square, 3: mesh.unit_cube}[dim](n))


def matrix(dim: int, n: int, scene: str = "heat"):
    """The scenes' default system matrix on that mesh (as ``benchmarks/crossover.py``): heat
    backward Euler ``M + dt κ K`` (κ 0.01, T 1, 100 steps), Newmark ``M + (c dt/2)² K`` (c 1, T 0.5, 50)."""
    d = discretization(dim, n)
    return (d.M + (0.01 / 100 if scene == "heat" else (0.5 / 50 / 2) ** 2) * d.K).tocsr()


@pytest.mark.parametrize("dim,n,scene", CASES)
@pytest.mark.parametrize("block", [True, False])
def test_amg_cg_agrees_with_the_direct_solve_to_its_tolerance(dim, n, scene, block):
    A = matrix(dim, n, scene)
    B = np.random.default_rng(1).standard_normal((A.shape[0], 5))
    X = SuperLU(A).solve(B)
    amg = AMGCG(A, rtol=1e-10, block=block)
    Y = amg.solve(B)
    # residual ≤ rtol‖b‖ per column, and the error ≤ cond(A)·rtol (A = M + small·K: cond ~ 10²)
    res = np.linalg.norm(B - A @ Y, axis=0) / np.linalg.norm(B, axis=0)
    assert res.max() <= 1e-10
    assert np.abs(Y - X).max() <= 1e-7 * np.abs(X).max()
    assert np.abs(Y - X).max() > 0  # an iterative answer, not the factorization's
    np.testing.assert_allclose(amg.solve(B[:, 0]), Y[:, 0], rtol=1e-8, atol=1e-12)  # (N,) in, (N,) out


def test_amg_cg_reports_its_tolerance_and_hierarchy():
    A = matrix(2, 48)
    amg = AMGCG(A, rtol=1e-9)
    amg.solve(np.ones(A.shape[0]))
    assert amg.rtol == 1e-9 and amg.levels >= 2 and amg.iterations >= 1
    nnz_all = sum(lvl.A.nnz for lvl in amg.ml.levels)
    assert amg.operator_complexity == pytest.approx(nnz_all / A.nnz)
    assert 1.0 < amg.operator_complexity < 2.0
    A_bytes = A.data.nbytes + A.indices.nbytes + A.indptr.nbytes
    assert A_bytes < amg.nbytes < 10 * A_bytes
    assert "rtol=1e-09" in repr(amg)


def test_the_block_solve_and_the_column_loop_reach_the_same_residual():
    A = matrix(2, 32)
    B = np.random.default_rng(2).standard_normal((A.shape[0], 4))
    B[:, 2] = 0.0  # a zero column converges at once and must stay zero (no 0/0)
    X = AMGCG(A, rtol=1e-11).solve(B)
    assert np.all(X[:, 2] == 0) and np.isfinite(X).all()
    assert (np.linalg.norm(B - A @ X, axis=0) <= 1e-11 * np.linalg.norm(B, axis=0) + 1e-300).all()


@pytest.mark.parametrize("dim", [2, 3])
def test_heat_adjoint_identity_with_amg_holds_to_about_rtol(dim):
    n = 16 if dim == 2 else 6
    d = discretization(dim, n)
    exact = Heat(d.M, d.K, steps=20, backend="steps", dim=dim)
    rtol = 1e-10
    op = Heat(d.M, d.K, steps=20, backend="steps", dim=dim, solver=amg_cg(rtol))
    assert isinstance(op.stepper.lu, AMGCG)
    assert dot_test(op) <= 100 * rtol
    x = np.random.default_rng(0).standard_normal((3, op.n_in))
    assert np.abs(op.forward(x) - exact.forward(x)).max() <= 1e-6 * np.abs(exact.forward(x)).max()


def test_the_hierarchy_is_built_once_for_all_steps_columns_and_the_adjoint(monkeypatch):
    import pyamg

    calls = []
    real = pyamg.smoothed_aggregation_solver
    monkeypatch.setattr(pyamg, "smoothed_aggregation_solver",
                        lambda *a, **k: calls.append(1) or real(*a, **k))
    d = discretization(2, 12)
    op = Heat(d.M, d.K, steps=15, backend="steps", solver=AMGCG)
    X = np.random.default_rng(0).standard_normal((4, op.n_in))
    op.adjoint(op.forward(X))
    op.forward(X[:1])
    wave = Wave(d.M, d.K, steps=10, solver=AMGCG)
    wave.adjoint(wave.forward(X))
    assert len(calls) == 2  # one per operator


def test_nonsymmetric_matrix_is_refused_with_a_clear_message():
    A = sp.random(30, 30, density=0.2, random_state=0) + 5 * sp.eye(30)
    with pytest.raises(ValueError, match="needs a symmetric matrix.*SuperLU"):
        AMGCG(A)
    assert isinstance(default_solver(A, dim=3), SuperLU)


@pytest.mark.parametrize("rtol", [0, 0.0, -1e-8, 1, 1.5, float("nan"), "1e-8", None])
def test_bad_tolerance_is_refused(rtol):
    A = matrix(2, 6)
    with pytest.raises(ValueError, match=r"rtol=.*0 < rtol < 1"):
        AMGCG(A, rtol=rtol)
    with pytest.raises(ValueError, match=r"rtol=.*0 < rtol < 1"):
        amg_cg(rtol)


def test_too_few_iterations_raise_a_convergence_error():
    A = matrix(2, 32)
    with pytest.raises(ConvergenceError, match="did not reach rtol"):
        AMGCG(A, rtol=1e-14, maxiter=2).solve(np.ones(A.shape[0]))


def test_the_crossover_is_lower_in_3d_than_in_2d():
    """Factor fill grows like N log N in 2-D and N^(4/3) in 3-D: one threshold cannot fit both. The
    premise measured: at about the same N the sparse LU of the 3-D matrix holds several times the
    fill per unknown of the 2-D one, and the 1-D factor stays tridiagonal (fill ~3 per unknown)."""
    import scipy.sparse.linalg as sla

    def fill(A):
        lu = sla.splu(A.tocsc())
        return (lu.L.nnz + lu.U.nnz) / A.shape[0]

    f1, f2, f3 = fill(matrix(1, 1024)), fill(matrix(2, 32)), fill(matrix(3, 10))  # ~1 000 unknowns each
    assert f1 <= 4 and f3 > 2 * f2, (f1, f2, f3)
    assert AMG_CROSSOVER[3] < AMG_CROSSOVER[2]
    assert AMG_CROSSOVER[1] is None  # 1-D: a tridiagonal factor is always cheapest


@pytest.mark.parametrize("dim", [2, 3])
def test_the_automatic_choice_flips_at_the_crossover_of_its_dimension(dim):
    c = AMG_CROSSOVER[dim]
    assert not uses_amg(c, dim) and uses_amg(c + 1, dim)
    between = AMG_CROSSOVER[3] + 1  # above the 3-D line, below the 2-D one
    assert uses_amg(between, 3) and not uses_amg(between, 2)
    assert not uses_amg(10**12, None) and not uses_amg(10**12, 1)


def test_default_solver_follows_the_rule_on_real_matrices(monkeypatch):
    A2, A3 = matrix(2, 12), matrix(3, 6)  # 121 and 125 unknowns
    monkeypatch.setitem(solvers.AMG_CROSSOVER, 2, 121)
    monkeypatch.setitem(solvers.AMG_CROSSOVER, 3, 124)
    direct = (Cholesky, SuperLU)
    assert isinstance(default_solver(A2, dim=2), direct)  # N = crossover: still direct
    assert isinstance(default_solver(A3, dim=3), AMGCG)  # N = crossover + 1
    assert isinstance(default_solver(A3), direct)  # dimension unknown: never AMG
    with pytest.raises(ValueError, match="dim=4 is not allowed"):
        default_solver(A3, dim=4)


def test_heat_passes_its_dimension_to_the_default_solver(monkeypatch):
    d = discretization(3, 6)
    monkeypatch.setitem(solvers.AMG_CROSSOVER, 3, d.N - 1)
    assert isinstance(Heat(d.M, d.K, steps=5, backend="steps", dim=3).stepper.lu, AMGCG)
    assert not isinstance(Heat(d.M, d.K, steps=5, backend="steps", dim=2).stepper.lu, AMGCG)


def test_existing_scenes_keep_their_direct_solver_at_default_sizes():
    import pdeinv

    for name in ("heat_1d", "heat_2d"):
        op = pdeinv.load_problem(name, backend="steps").operator
        assert not isinstance(op.stepper.lu, AMGCG), name
