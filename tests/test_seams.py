"""The physics seam: non-symmetric operators, transposed solves, declared output spaces, leapfrog sensors."""

import numpy as np
import pytest
import scipy.sparse as sp
from exact import dot_test, load

import pdeinv
from pdeinv import observe
from pdeinv.fem.advection import cellular_flow, convection, max_cell_peclet
from pdeinv.fem.forms import discretize
from pdeinv.fem.solvers import AMGCG, SuperLU, default_solver, is_symmetric
from pdeinv.inverse import TikhonovCG, default_inverse
from pdeinv.physics import Leapfrog
from pdeinv.physics.capabilities import observes_field


def _nonsymmetric(n=30, seed=0):
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=0.2, random_state=seed) + 5 * sp.eye(n)
    return sp.csc_matrix(A), rng.standard_normal((n, 3))


def test_superlu_transposed_solve_on_a_nonsymmetric_matrix():
    A, B = _nonsymmetric()
    lu = SuperLU(A)
    assert not lu.symmetric
    np.testing.assert_allclose(A @ lu.solve(B), B, atol=1e-12)
    np.testing.assert_allclose(A.T @ lu.solve_T(B), B, atol=1e-12)


def test_symmetric_only_solvers_refuse_a_nonsymmetric_matrix():
    A, _ = _nonsymmetric()
    with pytest.raises(ValueError, match="needs a symmetric matrix"):
        AMGCG(A)
    assert isinstance(default_solver(A), SuperLU)  # never Cholesky for a non-symmetric A


def test_advection_operator_is_not_symmetric_and_its_adjoint_is_exact():
    p = load("advection_diffusion_2d", n=8, speed=2.0, steps=10, backend="steps")
    op = p.operator
    assert not op.symmetric and not is_symmetric(op.stepper.A)
    P = op.forward(np.eye(op.n_in)).T
    assert np.abs(P - P.T).max() > 1e-3 * np.abs(P).max()  # the map itself is not symmetric
    assert dot_test(op) <= 1e-12
    assert op.kind == "steps" and op.modes is None
    with pytest.raises(ValueError, match="backend='modal' needs a symmetric operator"):
        load("advection_diffusion_2d", n=4).operator.__class__(
            p.disc.M, p.disc.K, C=op.C, backend="modal")


@pytest.mark.parametrize("backend, inverse", [("steps", "TikhonovCG"), ("auto", "SpectralTikhonov")])
def test_advection_inverse_round_trip_chosen_by_capability(backend, inverse):
    p = load("advection_diffusion_2d", n=8, steps=10, backend=backend)
    assert type(p.inverse_simulator).__name__ == inverse
    x, y = p.sample(3, seed=1)
    x0 = np.zeros_like(x)
    assert np.allclose(p.inverse(p.operator.forward(x0), x0), x0)  # exact at y = P x0
    assert np.mean(p.relative_error(p.inverse(y, x0), x)) < 0.1


def test_streamline_diffusion_is_symmetric_psd_along_the_flow_and_off_below_peclet_one():
    d = discretize(pdeinv.fem.mesh.unit_square(16))
    flow = cellular_flow(10.0)
    D = (convection(d, flow, 1e-3) - convection(d, flow, kappa=1e9)).toarray()  # δ = 0 for huge κ
    assert np.abs(D).max() > 0 and np.allclose(D, D.T, atol=1e-14)
    assert np.linalg.eigvalsh(D).min() > -1e-12
    assert max_cell_peclet(d, flow, 1e-3) > 1
    default = load("advection_diffusion_2d")  # defaults: Galerkin, cell Péclet < 1, no added diffusion
    kappa, speed = default.settings["kappa"], default.settings["speed"]
    assert max_cell_peclet(default.disc, cellular_flow(speed), kappa) < 1
    plain = convection(default.disc, cellular_flow(speed), kappa=1e9)
    assert abs(default.operator.C - plain).max() == 0


def test_sensor_records_are_plain_numbers_even_when_there_are_as_many_as_unknowns():
    """Verified bug: with n_out == N the Tikhonov inverse weighted sensor time series by the
    field mass matrix. The output space is declared, not guessed from shapes."""
    p = load("heat_sensors_2d", n=4, sensors=9, steps=10, record_every=10, backend="steps")
    assert p.operator.n_out == p.operator.n_in
    assert not observes_field(p.operator)
    assert p.inverse_simulator.M_out is None
    svd = load("heat_sensors_2d", n=4, sensors=9, steps=10, record_every=10, backend="svd").operator
    assert svd.modes.mass_out is None  # the SVD in Euclidean norm on the records side
    assert observes_field(load("heat_2d", n=4).operator)


def test_leapfrog_with_sensors_records_the_leapfrog_run():
    d = discretize(pdeinv.fem.mesh.unit_square(6))
    lumped = discretize(pdeinv.fem.mesh.unit_square(6), lumped=True).M
    S = observe.sensor_matrix(d, [[0.5, 0.5], [0.3, 0.6]])
    op = Leapfrog(lumped, d.K, T=0.6, steps=12).sensors(S, 4)
    assert dot_test(op) <= 1e-12
    x = np.random.default_rng(0).standard_normal((2, d.N))
    Y = op.forward(x).reshape(2, op.n_records, op.n_sensors)
    for r in range(3):
        short = Leapfrog(lumped, d.K, T=0.2 * (r + 1), steps=4 * (r + 1))
        np.testing.assert_allclose(Y[:, r], (S @ short.forward(x).T).T, rtol=1e-12, atol=1e-14)


def test_wave_sensors_scene_offers_leapfrog():
    p = load("wave_sensors_2d", n=6, steps=24, record_every=3, sensors=6, scheme="leapfrog")
    assert isinstance(p.operator.scheme, pdeinv.physics.schemes.Leapfrog)
    assert dot_test(p.operator) <= 1e-12


def test_default_inverse_chooses_by_capability_not_class():
    class Reversible(pdeinv.physics.Matrix):  # any operator that declares it, with final_state/reverse
        reversible = True

        def final_state(self, U0, V0=None):
            return U0, U0

        def reverse(self, UT, VT):
            return UT, VT

    op = Reversible(np.eye(3))
    assert type(default_inverse(op)).__name__ == "TimeReversal"

    class Undeclared(Reversible):  # the methods alone do not make it reversible: the declaration does
        reversible = False

    assert type(default_inverse(Undeclared(np.eye(3)))).__name__ == "TikhonovCG"
    assert type(default_inverse(pdeinv.physics.Matrix(np.eye(3)))).__name__ == "TikhonovCG"


def test_weyl_count_has_the_three_dimensional_constant():
    from pdeinv.physics.backends.modal import weyl_count

    class Box:
        measure, dim = 1.0, 3

    lam = 1e4  # N(λ) ≈ |Ω| λ^{3/2} / (6π²)
    assert weyl_count(Box, lam) == pytest.approx(lam**1.5 / (6 * np.pi**2) + 1)


def test_tikhonov_cg_solve_works_without_a_previous_call():
    """Verified bug: ``TikhonovCG.solve`` read state that only ``__call__`` had set."""
    p = load("heat_2d", n=6, backend="steps")
    cg = TikhonovCG(p.operator, p.disc.M, alpha=1e-6)
    x = p.sample(2, seed=0)[0]
    b = p.operator.adjoint((p.disc.M @ p.operator.forward(x).T).T)
    X, PX, rel = cg.solve(b, 1e-6)
    assert rel.max() <= 1e-10
    np.testing.assert_allclose(PX, p.operator.forward(X), atol=1e-12)
    lhs = p.operator.adjoint((p.disc.M @ p.operator.forward(X).T).T) + 1e-6 * (p.disc.M @ X.T).T
    np.testing.assert_allclose(lhs, b, atol=1e-8 * np.abs(b).max())


def test_export_writes_sensor_records_never_as_fields(tmp_path):
    """Same bug in the export: records with n_out == N were written as mesh fields."""
    import meshio

    from pdeinv.io.export import write_fields

    p = load("heat_sensors_2d", n=4, sensors=9, steps=10, record_every=10)
    x, y = p.sample(2, seed=0)
    names = meshio.read(write_fields(tmp_path / "s.vtu", p, x, x, y, y)).point_data
    assert not any(k.startswith("y_") for k in names) and "x_true_0" in names
    q = load("heat_2d", n=4)
    x, y = q.sample(2, seed=0)
    assert "y_obs_0" in meshio.read(write_fields(tmp_path / "f.vtu", q, x, x, y, y)).point_data


def test_trainer_measures_sensor_records_euclidean_even_when_there_are_as_many_as_unknowns():
    import torch

    from pdeinv.methods import GD

    p = load("heat_sensors_2d", n=4, sensors=9, steps=10, record_every=10)
    x, y = p.sample(3, seed=0)
    xhat = x + 0.3 * np.random.default_rng(1).standard_normal(x.shape) * np.abs(x).max()
    trainer = pdeinv.Trainer(p, GD(), steps=1, prior=None)
    got = trainer.evaluate(lambda _: torch.as_tensor(xhat), (x, y, torch.as_tensor(y)))
    r = p.operator.forward(xhat) - y
    assert got["y_err"] == pytest.approx(np.mean(np.linalg.norm(r, axis=1) / np.linalg.norm(y, axis=1)))
    assert got["y_err"] != pytest.approx(np.mean(p.disc.relative_error(p.operator.forward(xhat), y)))
