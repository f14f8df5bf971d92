"""Operators: exact adjoints, wave invariants, modal = stepping, batching."""

import numpy as np
import pytest
from exact import dot_test, load

import pdeinv
from pdeinv.fem.forms import discretize
from pdeinv.fem.solvers import amg_cg
from pdeinv.physics import Heat

# every operator and backend the problems can build, on small meshes
OPERATORS = {
    "heat_1d-be-steps": ("heat_1d", dict(n=32, backend="steps")),
    "heat_1d-be-modal": ("heat_1d", dict(n=32, backend="modal")),
    "heat_1d-cn-steps": ("heat_1d", dict(n=32, scheme="cn", backend="steps")),
    "heat_1d-cn-modal": ("heat_1d", dict(n=32, scheme="cn", backend="modal")),
    "heat_1d-P2": ("heat_1d", dict(n=16, element="P2")),
    "heat_2d-be-steps": ("heat_2d", dict(n=12, backend="steps")),
    "heat_2d-be-modal": ("heat_2d", dict(n=12, backend="modal")),
    "heat_2d-cn-steps": ("heat_2d", dict(n=12, scheme="cn", backend="steps")),
    "heat_2d-P2": ("heat_2d", dict(n=8, element="P2", backend="steps")),
    "wave_1d": ("wave_1d", dict(n=32)),
    "wave_1d-P2": ("wave_1d", dict(n=16, element="P2")),
    "wave_2d": ("wave_2d", dict(n=12)),
    "wave_2d-leapfrog": ("wave_2d", dict(n=12, scheme="leapfrog", steps=200)),
    "advection-be": ("advection_diffusion_2d", dict(n=12)),  # not symmetric: transposed solves
    "advection-cn-P2": ("advection_diffusion_2d", dict(n=6, element="P2", scheme="cn", steps=20)),
}


@pytest.fixture(params=list(OPERATORS), scope="module")
def op(request):
    name, kw = OPERATORS[request.param]
    return load(name, **kw).operator


def test_dot_product(op):
    assert dot_test(op) <= 1e-12


def test_transposed_view(op):
    assert dot_test(op.T) <= 1e-12
    assert op.T.T is op


def test_batched_equals_per_sample(op):
    rng = np.random.default_rng(1)
    X = rng.standard_normal((6, op.n_in))
    for f in (op.forward, op.adjoint):
        Y = f(X)
        single = np.stack([f(x) for x in X])
        assert Y.shape == (6, op.n_in)
        np.testing.assert_allclose(Y, single, rtol=0, atol=1e-13 * np.abs(Y).max())


def test_linearity(op):
    rng = np.random.default_rng(2)
    x, z = rng.standard_normal((2, 3, op.n_in))
    lhs = op.forward(2.5 * x - z)
    np.testing.assert_allclose(lhs, 2.5 * op.forward(x) - op.forward(z), atol=1e-12 * np.abs(lhs).max())


@pytest.mark.parametrize("name", ["heat_1d", "heat_2d"])
@pytest.mark.parametrize("scheme", ["be", "cn"])
def test_modal_equals_stepping_on_defaults(name, scheme):
    modal = load(name, scheme=scheme, backend="modal")
    steps = load(name, scheme=scheme, backend="steps")
    x, _ = modal.sample(16, seed=3)
    ym, ys = modal.operator.forward(x), steps.operator.forward(x)
    assert np.linalg.norm(ym - ys) / np.linalg.norm(ys) <= 1e-10
    r = np.random.default_rng(4).standard_normal(ys.shape)
    am, as_ = modal.operator.adjoint(r), steps.operator.adjoint(r)
    assert np.linalg.norm(am - as_) / np.linalg.norm(as_) <= 1e-10


def test_modal_keeps_few_modes_on_defaults():
    """The default heat_2d problem is ill-conditioned: most modes are dead at T."""
    op = load("heat_2d").operator
    assert op.backend.name == "modal" and "auto" in op.choice
    assert op.backend.k < 0.3 * op.n_in
    g = np.abs(op.backend.g)
    assert np.sum(g >= 1e-3 * g.max()) < 0.1 * op.n_in


def test_auto_takes_modal_on_a_coarse_mesh_where_weyl_over_counts():
    """n=16: Weyl's law predicts more modes than unknowns, yet all 225 dense modes beat 100 steps."""
    op = load("heat_2d", n=16).operator
    assert op.backend.name == "modal", op.choice


def test_auto_prefers_stepping_when_few_steps_and_slow_decay():
    """N = 2209, more than N/2 live modes: the modal form is offered only by the dense eigh
    (``modes.route``), whose ~9N³ flops lose to stepping in a short run (the one chooser weighs the
    whole run, compiled.plan)."""
    from pdeinv.physics.backends.compiled import expecting

    with expecting(steps=1):
        op = load("heat_2d", n=48, steps=2, kappa=1e-4).operator
    assert op.kind == "steps" and "modal≈" in op.choice, op.choice


def test_cn_modal_refused_when_high_modes_undamped():
    with pytest.raises(ValueError, match="Crank"):
        load("heat_1d", n=64, scheme="cn", steps=1, backend="modal")


def test_wave_energy_conserved_over_1e4_steps():
    p = load("wave_1d", n=32, T=50.0, steps=10_000)
    rng = np.random.default_rng(5)
    u0, v0 = rng.standard_normal((2, 3, p.N))
    uT, vT = p.operator.final_state(u0, v0)
    E0, ET = p.operator.energy(u0, v0), p.operator.energy(uT, vT)
    assert np.max(np.abs(ET - E0) / E0) <= 1e-12


def test_wave_reverse_returns_initial_state():
    op = load("wave_2d", n=16, steps=100).operator
    rng = np.random.default_rng(6)
    u0, v0 = rng.standard_normal((2, 4, op.n_in))
    back = op.reverse(*op.final_state(u0, v0))
    assert np.linalg.norm(back[0] - u0) / np.linalg.norm(u0) <= 1e-10
    assert np.linalg.norm(back[1] - v0) / np.linalg.norm(v0) <= 1e-10


def test_wave_forward_is_final_state_displacement():
    p = load("wave_1d", n=16, backend="steps")
    x, y = p.sample(3, seed=1)
    np.testing.assert_array_equal(p.operator.final_state(x)[0], y)
    compiled = load("wave_1d", n=16).operator  # auto: dense, the same map to rounding
    assert np.linalg.norm(compiled.forward(x) - y) <= 1e-12 * np.linalg.norm(y)


def test_amg_solver_matches_direct():
    p = load("heat_2d", n=16, backend="steps")
    direct = p.operator
    amg = Heat(p.disc.M, p.disc.K, kappa=direct.kappa, T=1.0, steps=20, backend="steps",
               solver=amg_cg(rtol=1e-13))
    ref = Heat(p.disc.M, p.disc.K, kappa=direct.kappa, T=1.0, steps=20, backend="steps")
    x, _ = p.sample(3, seed=0)
    assert np.linalg.norm(amg.forward(x) - ref.forward(x)) / np.linalg.norm(ref.forward(x)) < 1e-10
    assert dot_test(amg) < 1e-10  # AMG-CG solves to rtol, so the identity holds to ~rtol


def test_lumped_mass_is_diagonal_and_conserves_mass():
    m = pdeinv.fem.mesh.unit_square(8)
    full = discretize(m, dirichlet=False)
    lumped = discretize(m, dirichlet=False, lumped=True)
    assert (lumped.M - lumped.M.T).nnz == 0 and lumped.M.nnz == lumped.N
    assert np.isclose(lumped.M.sum(), full.M.sum()) and np.isclose(full.M.sum(), 1.0)


def test_neumann_heat_conserves_mass():
    m = pdeinv.fem.mesh.unit_square(8)
    d = discretize(m, dirichlet=False)
    for backend in ("steps", "modal"):
        op = Heat(d.M, d.K, kappa=0.1, T=1.0, steps=20, backend=backend)
        x = np.random.default_rng(0).standard_normal(d.N)
        ones = np.ones(d.N)
        assert np.isclose(ones @ d.M @ op.forward(x), ones @ d.M @ x, rtol=1e-10)


@pytest.mark.parametrize("scheme", ["be", "cn"])
def test_sparse_eigensolver_path_matches_stepping(monkeypatch, scheme):
    """Force the block Krylov eigensolve used on large meshes (1521 unknowns, ~110 modes)."""
    from pdeinv.physics.backends import modes

    monkeypatch.setattr(modes, "DENSE_MAX", 10)
    modal = load("heat_2d", n=40, scheme=scheme, backend="modal", kappa=0.02).operator
    steps = load("heat_2d", n=40, scheme=scheme, backend="steps", kappa=0.02).operator
    assert modal.backend.k > 64  # more than one block
    x = np.random.default_rng(0).standard_normal((4, modal.n_in))
    ys = steps.forward(x)
    assert np.linalg.norm(modal.forward(x) - ys) / np.linalg.norm(ys) <= 1e-10
    assert dot_test(modal) <= 1e-12


def test_reversibility_is_declared_by_the_scheme_not_found_by_name():
    """Newmark and leapfrog are both time-reversible: each declares it, runs the final state back to
    the initial one to rounding, and so gets the same default network and time-reversal inverse;
    a θ-scheme and a sensor observation are not reversible, and ``reverse`` says so."""
    from pdeinv.inverse.time_reversal import TimeReversal
    from pdeinv.physics.capabilities import reversible

    nets = {}
    for scheme, steps in (("newmark", 50), ("leapfrog", 400)):
        p = pdeinv.load_problem("wave_2d", n=12, scheme=scheme, steps=steps)
        op = p.operator.stepping()
        assert reversible(op)
        x = p.sample(3, 0)[0]
        uT, cT = op.final_state(x)
        np.testing.assert_allclose(uT, op.forward(x), rtol=0, atol=1e-13 * np.abs(uT).max())
        u0, _ = op.reverse(uT, cT)
        assert np.abs(u0 - x).max() <= 1e-12 * np.abs(x).max()
        inv = TimeReversal(op)
        assert np.abs(inv(op.forward(x), x) - x).max() <= 1e-12 * np.abs(x).max()
        nets[scheme] = type(p.model().base).__name__, p.model().decoder is None
    assert nets["newmark"] == nets["leapfrog"]
    heat = pdeinv.load_problem("heat_1d", n=16, steps=10).operator.stepping()
    sensed = pdeinv.load_problem("wave_sensors_2d", n=8).operator
    assert not reversible(heat) and not reversible(sensed)
    with pytest.raises(ValueError, match="not time-reversible"):
        heat.reverse(np.zeros(heat.n_in), np.zeros(heat.n_in))


def test_wave_takes_the_mesh_solver_for_short_runs_and_superlu_for_long_ones():
    """Wave's default solver: the mesh's (Cholesky where cholespy is installed) up to FAST_SOLVER_STEPS
    steps, SuperLU beyond (cholespy's systematic energy drift); both give the same final field."""
    from pdeinv.fem.forms import discretize
    from pdeinv.fem.solvers import SuperLU, solver_for
    from pdeinv.physics.wave import FAST_SOLVER_STEPS, Wave

    d = discretize(pdeinv.mesh.unit_square(12), "P1")
    short = Wave(d.M, d.K, steps=FAST_SOLVER_STEPS, dim=2)
    long = Wave(d.M, d.K, steps=FAST_SOLVER_STEPS + 1, dim=2)
    assert type(long.scheme.lu) is SuperLU
    assert type(short.scheme.lu) is type(solver_for(2)(short.scheme.A))
    lu = Wave(d.M, d.K, steps=FAST_SOLVER_STEPS, solver=SuperLU)
    x = np.random.default_rng(7).standard_normal((3, short.n_in))
    a, b = short.forward(x), lu.forward(x)
    assert np.abs(a - b).max() <= 1e-10 * np.abs(b).max()
