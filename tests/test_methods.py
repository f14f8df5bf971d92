"""Update rules, one step each, against the formula computed by hand on dense linear problems.

The toy problem is ``y = A x`` with a small dense, well-conditioned ``A`` wrapped
as ``pdeinv.physics.Matrix``; networks are float64 so the comparisons can be tight.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import nn

import pdeinv
from pdeinv.methods import GD, HIG, SIP, NonFiniteError, adam, sgd
from pdeinv.methods.hig import routes as hig_routes

pytestmark = pytest.mark.usefixtures("one_thread")  # small dense work: one torch thread


def toy(n=5, m=5, seed=0):
    """``A`` (m×n) with singular values in [0.5, 2], an exact inverse, random targets."""
    rng = np.random.default_rng(seed)
    U, _ = np.linalg.qr(rng.standard_normal((m, m)))
    V, _ = np.linalg.qr(rng.standard_normal((n, n)))
    S = np.zeros((m, n))
    np.fill_diagonal(S, np.linspace(2.0, 0.5, min(m, n)))
    A = U @ S @ V.T
    exact = lambda y, x0: np.linalg.lstsq(A, y.T, rcond=None)[0].T  # noqa: E731
    problem = SimpleNamespace(name="toy", operator=pdeinv.physics.Matrix(A), inverse=exact, noise=0.0,
                              disc=None)
    return problem, A, rng


def linear(m, n, seed=1, bias=True):
    torch.manual_seed(seed)
    model = nn.Linear(m, n, bias=bias, dtype=torch.float64)
    with torch.no_grad():
        model.weight.normal_(0, 0.3)
    return model


def numpy_params(model):
    return [p.detach().numpy().copy() for p in model.parameters()]


# -- GD -----------------------------------------------------------------------------------

def test_gd_sgd_step_is_the_adjoint_gradient():
    """W ← W − lr · (1/B) Σ Aᵀ r_i y_iᵀ,  b ← b − lr · (1/B) Σ Aᵀ r_i,  r_i = A(W y_i + b) − y_i."""
    problem, A, rng = toy()
    model = linear(5, 5)
    W, b = numpy_params(model)
    Y = rng.standard_normal((4, 5))
    lr = 0.3
    rule = GD(optimizer=sgd(lr), normalize=False)  # the raw gradient step
    state = rule.init(problem, model)
    state, info = rule.step(state, model, torch.tensor(Y))

    R = (A @ (Y @ W.T + b).T).T - Y
    assert info["loss"] == pytest.approx(0.5 * np.mean((R**2).sum(1)), rel=1e-12)
    gx = R @ A  # rows Aᵀ r_i
    np.testing.assert_allclose(model.weight.detach().numpy(), W - lr * gx.T @ Y / 4, rtol=0, atol=1e-13)
    np.testing.assert_allclose(model.bias.detach().numpy(), b - lr * gx.mean(0), rtol=0, atol=1e-13)
    assert state.steps == 1


def test_gd_takes_any_torch_optimizer():
    """First Adam step: θ ← θ − lr · g/(|g| + ε) (bias-corrected moments equal g and g²)."""
    problem, A, rng = toy()
    model = linear(5, 5, bias=False)
    (W,) = numpy_params(model)
    Y = rng.standard_normal((3, 5))
    rule = GD(optimizer=adam(1e-2), normalize=False)
    rule.step(rule.init(problem, model), model, torch.tensor(Y))
    G = (((A @ (Y @ W.T).T).T - Y) @ A).T @ Y / 3
    np.testing.assert_allclose(model.weight.detach().numpy(), W - 1e-2 * G / (np.abs(G) + 1e-8),
                               atol=1e-12)


# -- SIP ----------------------------------------------------------------------------------

def test_sip_step_matches_hand_formula():
    """x̃ = A⁺(y + η(y* − y)),  W ← W − lr · (1/B) Σ (x_i − x̃_i) y*_iᵀ."""
    problem, A, rng = toy()
    model = linear(5, 5)
    W, b = numpy_params(model)
    Y = rng.standard_normal((4, 5))
    eta, lr = 0.5, 0.2
    rule = SIP(eta=eta, optimizer=sgd(lr), normalize=False)  # the raw proxy gradient
    state, info = rule.step(rule.init(problem, model), model, torch.tensor(Y))

    X = Y @ W.T + b
    Yp = X @ A.T
    Xt = np.linalg.solve(A, (Yp + eta * (Y - Yp)).T).T
    assert info["loss"] == pytest.approx(0.5 * np.mean(((Yp - Y) ** 2).sum(1)), rel=1e-12)
    assert info["proxy"] == pytest.approx(0.5 * np.mean(((X - Xt) ** 2).sum(1)), rel=1e-12)
    np.testing.assert_allclose(model.weight.detach().numpy(), W - lr * (X - Xt).T @ Y / 4, atol=1e-13)
    np.testing.assert_allclose(model.bias.detach().numpy(), b - lr * (X - Xt).mean(0), atol=1e-13)


@pytest.mark.parametrize("with_target", [False, True])
def test_sip_in_chunks_of_rows_is_the_full_batch_update(monkeypatch, with_target):
    """Large (rows, N) arrays are split by rows (sip.CHUNK_ENTRIES): 7 rows in chunks of 2 give the
    full batch's direction, loss and proxy to rounding (weights 2/7, 2/7, 2/7, 1/7)."""
    from pdeinv.methods import sip as sip_module

    problem, A, rng = toy()
    model = linear(5, 5)
    Y = torch.tensor(rng.standard_normal((7, 5)))
    goal = torch.tensor(rng.standard_normal((7, 5))) if with_target else None
    rule = SIP(eta=0.5, normalize=False)
    state = rule.init(problem, model)
    full = rule.update(state, model, Y, goal)
    monkeypatch.setattr(sip_module, "CHUNK_ENTRIES", 10)  # 10 // 5 = 2 rows per chunk
    chunked = rule.update(state, model, Y, goal)
    for a, b in zip(full.direction, chunked.direction, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-14)
    for key in ("loss", "proxy"):
        assert chunked.info[key] == pytest.approx(full.info[key], rel=1e-12)


@pytest.mark.parametrize("rule", [SIP(eta=1.0, optimizer=sgd(3 / 1.7**2), normalize=False), SIP()],
                         ids=["raw-lr-B/c2", "default-normalized"])
def test_sip_exact_inverse_eta_one_lands_on_the_solution(rule):
    """Linear head, orthogonal targets of norm c, SGD lr = B/c² (= 1/λ_max of the proxy's Hessian
    c²/B, which the default normalization finds): after one step f(y*_i) = A⁻¹ y*_i."""
    problem, A, rng = toy()
    model = linear(5, 5, bias=False)
    c, B = 1.7, 3
    Y = c * np.linalg.qr(rng.standard_normal((5, B)))[0].T  # B orthogonal rows, ‖y_i‖ = c
    rule.step(rule.init(problem, model), model, torch.tensor(Y))
    X = model(torch.tensor(Y)).detach().numpy()
    np.testing.assert_allclose(X, np.linalg.solve(A, Y.T).T, atol=1e-12)
    assert np.abs(X @ A.T - Y).max() < 1e-12


def test_sip_uses_the_problem_inverse_by_default_and_checks_its_output():
    problem, A, rng = toy()
    calls = []
    problem.inverse = lambda y, x0: calls.append(y.shape) or x0[:, :-1]  # wrong shape
    model = linear(5, 5)
    rule = SIP()
    with pytest.raises(ValueError, match="inverse simulator returned shape"):
        rule.step(rule.init(problem, model), model, torch.tensor(rng.standard_normal((2, 5))))
    assert calls == [(2, 5)]


# -- HIG ----------------------------------------------------------------------------------

def hig_by_hand(A, W, b, Y, eta, tau, exponent):
    """Stacked J of y_i = A(W y_i + b) w.r.t. (vec W row-major, b); SVD, drop σ ≤ τσ_max."""
    J = np.concatenate([np.hstack([np.kron(A, y[None, :]), A]) for y in Y])
    g = ((Y @ W.T + b) @ A.T - Y).ravel()
    U, s, Vt = np.linalg.svd(J, full_matrices=False)
    k = s > tau * s[0]
    return -eta * Vt[k].T @ (s[k] ** exponent * (U[:, k].T @ g))


@pytest.mark.parametrize("route", ["svd", "gram"])
@pytest.mark.parametrize("jacobian", ["forward", "reverse"])
def test_hig_step_matches_hand_formula(route, jacobian):
    """Δθ = −η V Λ^{−1/2} Uᵀ g with rows = batch × n_out; both Jacobian and both decomposition routes."""
    problem, A, rng = toy(n=4, m=3)
    model = linear(3, 4)
    W, b = numpy_params(model)
    Y = rng.standard_normal((2, 3))  # 6 rows < 16 parameters
    rule = HIG(eta=0.7, tau=1e-3, route=route, jacobian=jacobian, normalize=False)
    state, info = rule.step(rule.init(problem, model), model, torch.tensor(Y))
    delta = hig_by_hand(A, W, b, Y, 0.7, 1e-3, -0.5)
    got = np.concatenate([(p - q).ravel() for p, q in zip(numpy_params(model), (W, b))])
    np.testing.assert_allclose(got, delta, rtol=1e-9, atol=1e-12)
    assert (info["route"], info["jacobian"]) == (route, jacobian)
    assert info["rank"] == 6


def test_hig_exponent_minus_one_is_gauss_newton():
    """e = −1, τ = 0, η = 1 on a tanh MLP: Δθ = −(JᵀJ)⁻¹ Jᵀ r, J by torch.autograd (full column rank)."""
    problem, A, rng = toy(n=3, m=3)
    torch.manual_seed(3)
    model = nn.Sequential(nn.Linear(3, 2), nn.Tanh(), nn.Linear(2, 3)).double()  # 17 parameters
    Y = torch.tensor(rng.standard_normal((8, 3)))  # 24 rows
    theta0 = torch.nn.utils.parameters_to_vector(model.parameters()).detach().clone()

    def y_of(theta):  # the same network written out by hand, so J does not come from torch.func
        W1, b1, W2, b2 = theta[:6].reshape(2, 3), theta[6:8], theta[8:14].reshape(3, 2), theta[14:]
        return (torch.tanh(Y @ W1.T + b1) @ W2.T + b2) @ torch.tensor(A).T

    J = torch.autograd.functional.jacobian(lambda t: y_of(t).reshape(-1), theta0).numpy()
    r = (y_of(theta0) - Y).reshape(-1).numpy()
    np.testing.assert_allclose(y_of(theta0).numpy(), (model(Y) @ torch.tensor(A).T).detach().numpy())
    gn = -np.linalg.solve(J.T @ J, J.T @ r)

    rule = HIG(eta=1.0, tau=0.0, exponent=-1.0)
    state, info = rule.step(rule.init(problem, model), model, Y)
    got = (torch.nn.utils.parameters_to_vector(model.parameters()) - theta0).detach().numpy()
    np.testing.assert_allclose(got, gn, rtol=1e-7, atol=1e-10)
    assert info["route"] == "svd" and info["rank"] == 17  # rows > parameters: the SVD route


def test_hig_drops_small_singular_values_never_clamps():
    """A direction with σ ≤ τσ_max gets no update at all (clamping would give it the largest)."""
    rng = np.random.default_rng(0)
    U = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    V = np.linalg.qr(rng.standard_normal((6, 3)))[0]
    s = np.array([1.0, 0.5, 1e-9])
    J = torch.tensor(U @ np.diag(s) @ V.T)
    g = torch.tensor(U @ np.ones(3))
    for decomposition in (hig_routes.SVD(), hig_routes.Gram()):
        delta, info = decomposition.direction(J, g, HIG(eta=1.0, tau=1e-6))
        assert info["rank"] == 2
        np.testing.assert_allclose(V.T @ delta.numpy(), [-1.0, -0.5**-0.5, 0.0], atol=1e-6)


def test_hig_auto_route_picks_gram_when_rows_are_few_and_svd_when_ill_conditioned():
    rng = np.random.default_rng(1)
    J = torch.tensor(rng.standard_normal((4, 40)))
    g = torch.tensor(rng.standard_normal(4))
    auto = hig_routes.auto_decomposition(4, 40, HIG().gram_cond_max)
    d_gram, info = auto.direction(J, g, HIG())
    d_svd, _ = hig_routes.SVD().direction(J, g, HIG())
    assert info["route"] == "gram"
    np.testing.assert_allclose(d_gram.numpy(), d_svd.numpy(), rtol=1e-10)
    U = np.linalg.qr(rng.standard_normal((4, 4)))[0]
    V = np.linalg.qr(rng.standard_normal((40, 4)))[0]
    J = torch.tensor(U @ np.diag([1, 1e-2, 1e-4, 1e-7]) @ V.T)  # cond 1e7 > gram_cond_max
    _, info = auto.direction(J, g, HIG(tau=1e-8))
    assert info["route"] == "svd" and info["gram_rejected"] > 1e6
    # its memory budget counts the SVD it may fall back to, not the Gram route's own
    assert auto.bytes_per_entry == hig_routes.SVD.bytes_per_entry > hig_routes.Gram.bytes_per_entry


def test_hig_refuses_a_jacobian_over_budget_before_computing_it():
    problem, A, rng = toy()
    model = linear(5, 5)
    rule = HIG(max_jacobian_gb=1e-7)
    with pytest.raises(ValueError, match=r"HIG Jacobian of 20 rows \(batch 4 × 5 observations\) × 30 "
                                         r"parameters needs about .* GB.*batch_size"):
        rule.step(rule.init(problem, model), model, torch.tensor(rng.standard_normal((4, 5))))


@pytest.mark.parametrize("kw", [dict(eta=0), dict(tau=-1), dict(tau=1.0), dict(route="qr"),
                                dict(jacobian="fd")])
def test_hig_bad_settings_are_refused(kw):
    with pytest.raises(ValueError, match="not allowed"):
        HIG(**kw)


# -- non-finite values are never trained on -------------------------------------------------

@pytest.mark.parametrize("rule", [GD(optimizer=sgd(0.1)), SIP(optimizer=sgd(0.1)), HIG()],
                         ids=["gd", "sip", "hig"])
def test_non_finite_output_raises_and_leaves_parameters_alone(rule):
    problem, A, rng = toy()
    model = linear(5, 5)
    with torch.no_grad():
        model.weight[0, 0] = float("inf")
    before = numpy_params(model)
    with pytest.raises(NonFiniteError, match="not finite"):
        rule.step(rule.init(problem, model), model, torch.tensor(rng.standard_normal((2, 5))))
    for p, q in zip(numpy_params(model), before):
        np.testing.assert_array_equal(p, q)


def test_non_finite_inverse_output_is_refused():
    problem, A, rng = toy()
    problem.inverse = lambda y, x0: np.full_like(x0, np.nan)
    model = linear(5, 5)
    rule = SIP(optimizer=sgd(0.1))
    with pytest.raises(NonFiniteError, match="inverse simulator"):
        rule.step(rule.init(problem, model), model, torch.tensor(rng.standard_normal((2, 5))))
