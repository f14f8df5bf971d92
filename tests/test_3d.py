"""3-D scenes (tetrahedra): heat_3d, wave_3d, heat_cavity_3d, heat_sensors_3d — the 2-D template applied.

Proves: the fitted L² rates in the unit cube (P1 → 2, P2 → 3) against the separable
exact solutions ``u₀ = sin πx sin πy sin πz`` (λ = 3π²): heat ``e^{−3π²κT} u₀``, wave
``cos(√3 π c T) u₀``; the adjoint is the exact transpose (dot product, gradcheck, Taylor
rate 2 through a network); the local inverse returns x₀ when y = P x₀ and reduces the
misfit otherwise; the cavity scene puts u = 0 on the cavity only; a short CLI run on a
tiny cube learns.
"""

import json

import numpy as np
import pytest
import torch
from exact import dot_test, eigenvalue, fitted_rate, l2_error, load, mode, taylor_rates_through_network

import pdeinv
from pdeinv.cli import main

# Time error kept out of the spatial rate: Crank–Nicolson (heat) and Newmark (wave), both
# second order, with dt small against 1/λ. Short T: on these coarse meshes the O(h⁴) error
# of the discrete eigenvalue (P2) would otherwise lift the fitted rate above 3
# (heat P2 with T=0.05 fits 3.26; T=0.01 fits 3.00).
SPACE = {  # id: (problem, element, mesh sizes, expected rate, T, steps, exact factor at T)
    "heat-P1": ("heat_3d", "P1", [6, 8, 12], 2, 0.01, 100, lambda T: np.exp(-eigenvalue(3) * T)),
    "heat-P2": ("heat_3d", "P2", [2, 3, 4, 6], 3, 0.01, 100, lambda T: np.exp(-eigenvalue(3) * T)),
    "wave-P1": ("wave_3d", "P1", [6, 8, 12], 2, 0.1, 50, lambda T: np.cos(np.sqrt(eigenvalue(3)) * T)),
    "wave-P2": ("wave_3d", "P2", [2, 3, 4, 6], 3, 0.1, 100, lambda T: np.cos(np.sqrt(eigenvalue(3)) * T)),
}
SCHEME = {"heat_3d": dict(kappa=1.0, scheme="cn"), "wave_3d": dict(c=1.0)}


@pytest.mark.parametrize("case", list(SPACE))
def test_space_rate(case):
    name, element, ns, rate, T, steps, factor = SPACE[case]
    errs = []
    for n in ns:
        p = load(name, n=n, element=element, T=T, steps=steps, backend="steps", **SCHEME[name])
        assert p.points.shape[0] == 3
        errs.append(l2_error(p.disc, p.operator.forward(mode(p.points)), factor(T)))
    assert abs(fitted_rate(1.0 / np.array(ns), errs) - rate) < 0.2, errs


# tiny versions of every 3-D scene and backend the scenes build by default
SMALL = {
    "heat-modal": ("heat_3d", dict(n=4, steps=5, kappa=0.05, backend="modal")),
    "heat-steps-P2": ("heat_3d", dict(n=2, steps=5, kappa=0.05, element="P2", backend="steps")),
    "wave": ("wave_3d", dict(n=4, steps=5)),
    "wave-P2": ("wave_3d", dict(n=2, steps=5, element="P2")),
    "cavity": ("heat_cavity_3d", dict(steps=5, backend="steps")),
    "sensors": ("heat_sensors_3d", dict(n=4, steps=6, record_every=2, sensors=5, backend="steps")),
}


@pytest.fixture(params=list(SMALL), scope="module")
def problem(request):
    name, kw = SMALL[request.param]
    return load(name, **kw)


def test_dot_product(problem):
    assert dot_test(problem.operator) <= 1e-12


def test_gradcheck(problem):
    """gradcheck of ``z ↦ Wᵀ P(x₀ + V z)`` with random ``V``, ``W`` of 4 columns (cheap for the
    cavity's 1090 unknowns; the bridge's backward is still the operator's adjoint)."""
    op = problem.operator
    gen = torch.Generator().manual_seed(0)
    V = torch.randn(op.n_in, 4, dtype=torch.float64, generator=gen)
    W = torch.randn(op.n_out, 4, dtype=torch.float64, generator=gen)
    x0 = torch.randn(2, op.n_in, dtype=torch.float64, generator=gen)
    z = torch.randn(2, 4, dtype=torch.float64, generator=gen, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: pdeinv.apply(op, x0 + t @ V.T) @ W, (z,))


def test_taylor_remainder_through_network(problem):
    """J(θ+εd) − J(θ) − ε∇J·d = O(ε²) for J(θ) = ½‖P f(y; θ) − y*‖², f a tanh MLP."""
    rates = taylor_rates_through_network(problem, hidden=8, samples=3, eps=1e-3 * 0.5 ** np.arange(5))
    assert rates.min() > 1.9, rates


def test_inverse_round_trip_and_descent(problem):
    """``P⁻¹_(x₀, P x₀)(P x₀) = x₀``; for another y the local inverse lowers the misfit."""
    x0, y0 = problem.sample(2, seed=1)
    np.testing.assert_allclose(problem.inverse(y0, x0), x0, rtol=0, atol=1e-10 * np.abs(x0).max())
    x1, y1 = problem.sample(1, seed=2)
    xt = problem.inverse(y1, x0[:1])
    before = np.linalg.norm(problem.operator.forward(x0[:1]) - y1, axis=1)
    after = np.linalg.norm(problem.operator.forward(xt) - y1, axis=1)
    assert (after < 0.5 * before).all(), (before, after)


def test_cavity_is_cold_and_the_outside_insulated():
    """Default: Dirichlet on the cavity only (the outer faces' unknowns are free); with
    ``dirichlet=outer,cavity`` both are fixed, and the unknowns are the interior nodes."""
    p = load("heat_cavity_3d", steps=5, backend="steps")
    m = p.disc.basis.mesh
    on_cube = np.isclose(np.abs(m.p - 0.5).max(axis=0), 0.5)
    r = np.linalg.norm(m.p - np.array([[0.45], [0.55], [0.5]]), axis=0)
    assert p.N == m.p.shape[1] - np.isclose(r, 0.25).sum()
    assert on_cube[p.disc.free].sum() == on_cube.sum()
    both = load("heat_cavity_3d", steps=5, backend="steps", dirichlet="outer,cavity")
    assert both.N == m.p.shape[1] - on_cube.sum() - np.isclose(r, 0.25).sum()
    with pytest.raises(ValueError, match=r"boundary 'rim' is not a named boundary.*\['cavity', 'outer'\]"):
        load("heat_cavity_3d", dirichlet="rim")


def test_auto_backend_in_3d():
    """Weyl's 3-D count (|Ω|λ^{3/2}/6π²) steers ``auto`` to the modal operator on the default cube."""
    op = load("heat_3d", n=6).operator
    assert op.choice.startswith("auto: modal"), op.choice
    ref = load("heat_3d", n=6, backend="steps").operator
    x = np.random.default_rng(0).standard_normal((3, op.n_in))
    np.testing.assert_allclose(op.forward(x), ref.forward(x), rtol=0, atol=1e-12)


def test_weyl_count_in_3d_errs_on_the_safe_side():
    """The 3-D Weyl count ``|Ω|λ^{3/2}/(6π²)`` (leading term, asked for by the modal backend)
    is at least the number of discrete Dirichlet eigenvalues below λ, and not absurdly more."""
    import scipy.linalg as la

    from pdeinv.physics.backends.modal import weyl_count

    p = load("heat_3d", n=6, backend="steps")
    lam = la.eigh(p.disc.K.toarray(), p.disc.M.toarray(), eigvals_only=True)
    for cut in (100.0, 300.0, 1000.0):
        count = int((lam < cut).sum())
        assert count <= weyl_count(p.operator, cut) <= 10 * count + 20, (cut, count)


def test_cli_training_learns(tmp_path):
    out = tmp_path / "run"
    argv = ["train", "--prior-fit", "0",
            "heat_3d", "--set", "n=4", "--steps", "50", "--n-train", "64", "--n-test", "16",
            "--batch-size", "16", "--threads", "1", "--seed", "0", "--out", str(out)]
    assert main(argv) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["problem"] == "heat_3d" and m["steps"] == 50
    p = load("heat_3d", n=4)
    x, y = p.sample(16, seed=12345)
    assert m["x_err"] < 0.9 * float(np.mean(p.relative_error(np.zeros_like(x), x))), m["x_err"]
    assert (out / "fields.vtu").is_file() and (out / "fields.png").is_file()
