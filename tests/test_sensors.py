"""Sensor time series (heat, wave) and the plate-with-a-hole mesh file problem.

Proves: the sensor adjoints are the exact transposes (dot product, gradcheck,
Taylor rate 2), the y layout is record-major, sensors interpolate the field,
the degenerate case (all nodes, final step only) is the plain operator, bad
input is refused by name, and the plate problem is built from its file with
Dirichlet only on the outer boundary.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch
from exact import dot_test, load

import pdeinv
from pdeinv import observe
from pdeinv.fem.forms import discretize
from pdeinv.physics import Heat, Wave, sensors

ROOT = Path(__file__).resolve().parents[1]

# tiny sensor scenes: every operator variant the two problems can build
SCENES = {
    "heat-be": ("heat_sensors_2d", dict(n=6, steps=10, record_every=2, sensors=5)),
    "heat-cn": ("heat_sensors_2d", dict(n=6, steps=10, record_every=5, sensors=4, scheme="cn")),
    "heat-P2": ("heat_sensors_2d", dict(n=4, steps=6, record_every=3, sensors=6, element="P2")),
    "wave-neumann": ("wave_sensors_2d", dict(n=6, steps=12, record_every=3, sensors=10)),
    "wave-dirichlet": ("wave_sensors_2d", dict(n=6, steps=12, record_every=2, sensors=8,
                                               boundary="dirichlet")),
    "wave-P2": ("wave_sensors_2d", dict(n=4, steps=8, record_every=1, sensors=7, element="P2")),
}


@pytest.fixture(params=list(SCENES), scope="module")
def problem(request):
    name, kw = SCENES[request.param]
    return load(name, **kw)


def test_shapes(problem):
    op = problem.operator
    assert op.n_in == problem.N
    assert op.n_out == op.n_sensors * op.n_records == op.n_sensors * op.steps // op.record_every
    x, y = problem.sample(2, seed=0)
    assert y.shape == (2, op.n_out)


def test_dot_product(problem):
    assert dot_test(problem.operator) <= 1e-12
    assert dot_test(problem.operator.T) <= 1e-12


def test_batched_equals_per_sample(problem):
    op = problem.operator
    rng = np.random.default_rng(1)
    for f, n in ((op.forward, op.n_in), (op.adjoint, op.n_out)):
        X = rng.standard_normal((5, n))
        Y = f(X)
        single = np.stack([f(x) for x in X])
        np.testing.assert_allclose(Y, single, rtol=0, atol=1e-13 * np.abs(Y).max())


@pytest.mark.parametrize("name", ["heat-be", "wave-neumann"])
def test_gradcheck_through_bridge(name):
    p = load(SCENES[name][0], **SCENES[name][1])
    x = torch.randn(2, p.N, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: pdeinv.apply(p.operator, x), (x,), eps=1e-6, atol=1e-8)


@pytest.mark.parametrize("name", ["heat-be", "wave-dirichlet"])
def test_taylor_remainder_rate(name):
    """J(x) = ½‖Px − y*‖²: |J(x+εd) − J(x) − ε∇J·d| = O(ε²) with the adjoint gradient (via torch)."""
    p = load(SCENES[name][0], **SCENES[name][1])
    rng = np.random.default_rng(3)
    ystar = torch.from_numpy(rng.standard_normal(p.operator.n_out))
    x = torch.from_numpy(rng.standard_normal(p.N)).requires_grad_(True)
    d = torch.from_numpy(rng.standard_normal(p.N))

    def J(x):
        return 0.5 * ((pdeinv.apply(p.operator, x) - ystar) ** 2).sum()

    J0 = J(x)
    (g,) = torch.autograd.grad(J0, x)
    eps = np.array([1e-1, 5e-2, 2.5e-2, 1.25e-2, 6.25e-3])
    rem = [abs(float(J(x.detach() + e * d) - J0.detach() - e * (g @ d))) for e in eps]
    rate = np.polyfit(np.log(eps), np.log(rem), 1)[0]
    assert rate >= 1.95, (rate, rem)


def test_layout_is_record_major():
    """Record r of a run with record_every=k is S times the plain operator after (r+1)k steps."""
    d = discretize(pdeinv.fem.mesh.unit_square(6))
    S = observe.sensor_matrix(d, observe.interior_points(d.basis.mesh, 3))
    x = np.random.default_rng(0).standard_normal((2, d.N))
    for Op, Sens, kw in ((Heat, sensors, dict(kappa=0.05, backend="steps")), (Wave, sensors, {})):
        op = Sens(Op(d.M, d.K, T=1.2, steps=12, **kw), S, record_every=4)
        Y = op.forward(x).reshape(2, op.n_records, op.n_sensors)
        for r in range(op.n_records):
            plain = Op(d.M, d.K, T=0.4 * (r + 1), steps=4 * (r + 1), **kw)
            np.testing.assert_allclose(Y[:, r], (S @ plain.forward(x).T).T, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(op.times(op.dt), [0.4, 0.8, 1.2])


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_sensor_at_a_node_reads_the_nodal_value(element):
    d = discretize(pdeinv.fem.mesh.unit_square(5), element)
    idx = np.array([0, 3, d.N // 2, d.N - 1])
    S = observe.sensor_matrix(d, d.points[:, idx].T)
    u = np.random.default_rng(2).standard_normal(d.N)
    np.testing.assert_allclose(S @ u, u[idx], rtol=0, atol=1e-13)


@pytest.mark.parametrize("kind", ["heat", "wave"])
def test_all_nodes_final_step_only_is_the_plain_operator(kind):
    d = discretize(pdeinv.fem.mesh.unit_square(6))
    S = observe.sensor_matrix(d, d.points.T)
    if kind == "heat":
        plain = Heat(d.M, d.K, kappa=0.05, steps=8, backend="steps")
        op = sensors(plain, S, record_every=8)
    else:
        plain = Wave(d.M, d.K, steps=8)
        op = sensors(plain, S, record_every=8)
    assert op.n_out == op.n_in == d.N
    x = np.random.default_rng(0).standard_normal((3, d.N))
    for mine, ref in ((op.forward, plain.forward), (op.adjoint, plain.adjoint)):
        a, b = mine(x), ref(x)
        assert np.linalg.norm(a - b) / np.linalg.norm(b) <= 1e-12


def test_heat_sensors_reuse_a_stepping_backend():
    d = discretize(pdeinv.fem.mesh.unit_square(6))
    S = observe.sensor_matrix(d, [[0.5, 0.5]])
    stepping = Heat(d.M, d.K, backend="steps")
    # one θ-step (one factorization) shared by the final-field backend and the sensor run
    assert sensors(stepping, S).scheme is stepping.stepper is stepping.scheme
    modal = Heat(d.M, d.K, kappa=0.05, steps=10, backend="modal")
    stepped = Heat(d.M, d.K, kappa=0.05, steps=10, backend="steps")
    op, ref = sensors(modal, S, 10), sensors(stepped, S, 10)
    x = np.random.default_rng(0).standard_normal((2, d.N))
    np.testing.assert_allclose(op.forward(x), ref.forward(x), rtol=1e-12)


def test_boundary_sensors_sit_on_the_boundary_and_inset_moves_them_inside():
    m = pdeinv.fem.mesh.unit_square(8)
    on = observe.boundary_points(m, 12)
    assert np.allclose(np.min(np.stack([on, 1 - on]), axis=(0, 2)), 0)
    inset = observe.boundary_points(m, 12, inset=0.125)
    dist = np.min(np.stack([inset, 1 - inset]), axis=(0, 2))  # to the nearest side
    np.testing.assert_allclose(dist, 0.125)  # exactly inset from every side, corners included
    inside = observe.interior_points(m, 7)
    assert inside.shape == (7, 2) and len(observe.outside(m, inside)) == 0


@pytest.mark.parametrize("n, sensors", [(3, 3), (4, 8), (5, 4)])
def test_dirichlet_sensors_near_corners_are_moved_off_both_sides(n, sensors):
    """Regression (found by the property tests): a sensor at a corner, moved along one side's
    normal only, stayed on the other side and read 0 on a Dirichlet wall."""
    p = load("wave_sensors_2d", n=n, sensors=sensors, boundary="dirichlet", steps=2, record_every=1)
    P = p.settings["sensor_points"]
    np.testing.assert_allclose(np.min(np.stack([P, 1 - P]), axis=(0, 2)), 1 / n)
    assert np.all(np.abs(p.operator.S).sum(axis=1) > 0)


def test_string_overrides_from_the_cli():
    p = load("wave_sensors_2d", n=4, steps="6", record_every="3", sensors="[[0.5, 0.5], [0.25, 0.0]]")
    assert p.operator.n_sensors == 2 and p.operator.n_records == 2
    assert load("heat_sensors_2d", n=4, steps=4, record_every=2, sensors="3").operator.n_sensors == 3


# -- bad input --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, overrides, match", [
    ("wave_sensors_2d", dict(sensors=[[0.5, 0.5], [1.5, 0.5]]),
     r"outside the mesh.*sensor 1 at \[1.5, 0.5\]"),
    ("heat_sensors_2d", dict(sensors=[[-0.1, 0.2]]), r"outside the mesh.*allowed: points inside"),
    ("heat_sensors_2d", dict(sensors=[[0.0, 0.5]]), r"sensor 0 at \[0.0, 0.5\].*Dirichlet boundary"),
    ("wave_sensors_2d", dict(boundary="dirichlet", sensors=[[0.5, 1.0]]), r"Dirichlet boundary"),
    ("wave_sensors_2d", dict(sensors=[]), r"(empty|expected \(n, 2\))"),
    ("wave_sensors_2d", dict(sensors=np.zeros((0, 2))), r"empty"),
    ("heat_sensors_2d", dict(sensors=0), r"sensors=0.*integer >= 1"),
    ("heat_sensors_2d", dict(sensors="abc"), r"sensors='abc'.*integer count >= 1 or coordinates"),
    ("heat_sensors_2d", dict(sensors=[[0.5, 0.5, 0.5]]), r"shape \(1, 3\); expected \(n, 2\)"),
    ("heat_sensors_2d", dict(sensors=[[np.nan, 0.5]]), r"NaN"),
    ("wave_sensors_2d", dict(record_every=0), r"record_every=0.*integer >= 1"),
    ("wave_sensors_2d", dict(steps=10, record_every=3),
     r"record_every=3 does not divide steps=10.*1, 2, 5, 10"),
    ("heat_sensors_2d", dict(backend="modal"), r"backend='modal'.*auto.*steps.*dense.*svd"),
    ("heat_plate", dict(refine=-1), r"refine=-1.*integer >= 0"),
])
def test_bad_inputs(name, overrides, match):
    kw = dict(n=4, steps=4, record_every=1) if name != "heat_plate" else dict(steps=4)
    with pytest.raises(ValueError, match=match):
        load(name, **{**kw, **overrides})


def test_bad_operator_arrays():
    op = load("heat_sensors_2d", n=4, steps=4, sensors=2, record_every=2).operator
    with pytest.raises(ValueError, match=rf"shape \(1, 5\); expected \(B, {op.n_out}\)"):
        op.adjoint(np.zeros((1, 5)))


# -- the plate mesh file ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def plate():
    return load("heat_plate", refine=0, backend="steps", steps=20)


def test_plate_file_is_what_the_script_makes():
    spec = importlib.util.spec_from_file_location("make_plate", ROOT / "problems/meshes/make_plate.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    made, shipped = mod.plate(), pdeinv.fem.mesh.load(ROOT / "problems/meshes/plate.msh")
    np.testing.assert_allclose(shipped.p, made.p, atol=1e-12)
    np.testing.assert_array_equal(shipped.t, made.t)
    assert sorted(shipped.boundaries) == sorted(made.boundaries) == ["hole", "outer"]
    for name in made.boundaries:
        np.testing.assert_array_equal(np.sort(shipped.boundaries[name]), np.sort(made.boundaries[name]))


def test_plate_dirichlet_on_outer_boundary_only(plate):
    basis = plate.disc.basis
    fixed = np.setdiff1d(np.arange(basis.N), plate.disc.free)
    x = basis.doflocs[:, fixed]
    assert np.allclose(np.max(np.abs(x - 0.5), axis=0), 0.5)  # all fixed dofs on the square
    hole = np.abs(np.linalg.norm(basis.doflocs - np.array([[0.42], [0.56]]), axis=0) - 0.2) < 1e-9
    assert hole.sum() == 64 and np.isin(np.flatnonzero(hole), plate.disc.free).all()
    assert abs(plate.disc.measure - (1 - np.pi * 0.2**2)) < 2e-3  # a 64-gon hole


def test_plate_operator_and_inverse_round_trip(plate):
    assert dot_test(plate.operator) <= 1e-12
    x0, y0 = plate.sample(3, seed=0)
    back = plate.inverse(y0, x0)
    assert np.linalg.norm(back - x0) / np.linalg.norm(x0) <= 1e-8
    # and from a perturbed start the local inverse moves toward x0
    x1 = x0 + 0.1 * plate.sample(3, seed=1)[0]
    err = plate.relative_error(plate.inverse(y0, x1), x0)
    assert np.all(err < plate.relative_error(x1, x0))


def test_plate_default_p2_loads():
    p = load("heat_plate", refine=0, element="P2", backend="steps", steps=5)
    assert p.N == p.disc.basis.N - 2 * 64  # outer loop: 64 nodes + 64 edge midpoints
    assert dot_test(p.operator) <= 1e-12


def test_a_long_sensor_list_goes_through_the_finder_in_chunks(monkeypatch):
    """Chunks of the element finder and probes (pdeinv.fem.sensors.CHUNK) give the same sensor matrix and
    the same points outside as one call (one call at 10⁶ sensors needed a 5.45 GiB temporary)."""
    p = pdeinv.load_problem("heat_sensors_2d", n=8, sensors=5)
    disc = p.disc
    rng = np.random.default_rng(0)
    pts = rng.uniform(0.05, 0.95, (50, 2))
    pts[[3, 17, 41]] = [[1.5, 0.5], [-0.2, 0.3], [0.5, 2.0]]
    whole = observe.outside(disc.basis.mesh, pts)
    inside = np.delete(pts, whole, axis=0)
    S = observe.sensor_matrix(disc, inside).toarray()
    monkeypatch.setattr(observe, "CHUNK", 7)
    assert observe.outside(disc.basis.mesh, pts).tolist() == whole.tolist() == [3, 17, 41]
    assert np.array_equal(observe.sensor_matrix(disc, inside).toarray(), S)
