"""Matrix-free HIG (randomized truncated SVD from jvp/vjp products) against the exact Jacobian routes."""

import numpy as np
import pytest
import torch
from exact import load

from pdeinv import HIG
from pdeinv.nets import MLP


@pytest.fixture(scope="module")
def scene():
    p = load("heat_1d", n=16, steps=10)
    torch.manual_seed(0)
    model = MLP(p.operator.n_out, p.N, hidden=(8,)).double()  # float64: the exact route is exact too
    _, y = p.sample(3, 0)
    return p, model, torch.tensor(y)


def _delta(p, model, y, wrap=False, **kw):
    """The parameter change of one HIG step from ``model`` (left unchanged) and the step's info;
    ``wrap``: inside an ``nn.Sequential``, which HIG's last-layer route does not take."""
    m = MLP(p.operator.n_out, p.N, hidden=(8,)).double()
    m.load_state_dict(model.state_dict())
    m = torch.nn.Sequential(m) if wrap else m
    rule = HIG(**{"normalize": False, **kw})  # the raw step: each route would scale by its own σ_max
    _, info = rule.step(rule.init(p, m), m, y)
    flat = lambda net: torch.cat([q.detach().flatten() for q in net.parameters()])  # noqa: E731
    return flat(m) - flat(model), info


@pytest.mark.parametrize("exponent", [-0.5, -1.0])
def test_full_rank_sketch_equals_the_exact_svd_step(scene, exponent):
    p, model, y = scene
    rows = 3 * p.operator.n_out  # 45 rows < 263 parameters: 45 probes see all of J
    exact, ie = _delta(p, model, y, eta=0.5, tau=1e-6, exponent=exponent, route="svd")
    sketch, ir = _delta(p, model, y, eta=0.5, tau=1e-6, exponent=exponent, route="randomized", probes=rows)
    assert ir["route"] == "randomized" and ir["rank"] == ie["rank"] and not ir["rank_limited"]
    assert ie["cond"] > 1e5  # an ill-conditioned J, where the power step's squaring could hurt
    assert float((sketch - exact).norm() / exact.norm()) < 1e-8


def test_a_capped_sketch_says_so_and_is_repeatable(scene):
    p, model, y = scene
    a, info = _delta(p, model, y, route="randomized", probes=10)
    b, _ = _delta(p, model, y, route="randomized", probes=10)
    c, _ = _delta(p, model, y, route="randomized", probes=10, seed=1)
    assert info["rank"] == 10 and info["rank_limited"]
    assert torch.equal(a, b) and not torch.equal(a, c)  # probes from SeedSequence([seed, step])


def test_capped_sketch_with_power_iterations_finds_the_top_subspace(scene):
    """With a spectral gap, the rank-k sketch reproduces the exact step restricted to the top k σ."""
    p, model, y = scene
    exact, ie = _delta(p, model, y, eta=1.0, tau=0.0, route="svd")
    k = 8
    # the exact top-k step, by hand from the SVD of the dense Jacobian
    from torch.func import functional_call, jacrev

    from pdeinv.physics.bridge import apply
    params = {n: q.detach() for n, q in model.named_parameters()}
    jac = jacrev(lambda prm: apply(p.operator, functional_call(model, prm, (y,))))(params)
    J = torch.cat([jac[n].reshape(y.numel(), -1) for n in params], 1).numpy()
    with torch.no_grad():
        g = (apply(p.operator, model(y)) - y).reshape(-1).numpy()
    U, s, Vt = np.linalg.svd(J, full_matrices=False)
    top = -(Vt[:k].T @ (s[:k] ** -0.5 * (U[:, :k].T @ g)))
    sketch, info = _delta(p, model, y, eta=1.0, tau=0.0, route="randomized", probes=k + 8, power_iters=4)
    assert s[k - 1] / s[k + 8] > 10  # the gap the power iterations exploit
    # the sketch keeps k + 8 directions; its top-k part matches the exact top-k step
    proj = Vt[:k].T @ (Vt[:k] @ sketch.numpy())
    assert np.linalg.norm(proj - top) / np.linalg.norm(top) < 1e-3


def test_auto_goes_matrix_free_only_when_the_dense_jacobian_does_not_fit(scene):
    p, model, y = scene
    # dense (gram route, 45 × 263 float32 + float64) ≈ 142 kB; the 10-probe sketch ≈ 70 kB; the MLP's
    # last-layer step (pdeinv.methods.hig.layers) ≈ 2 kB: a dense network takes that instead
    _, info = _delta(p, model, y, route="auto", probes=10, max_jacobian_gb=100e3 / 2**30)
    assert info["route"] == "last_layer"
    _, info = _delta(p, model, y, wrap=True, route="auto", probes=10, max_jacobian_gb=100e3 / 2**30)
    assert info["route"] == "randomized" and info["jacobian"] == "matrix-free"
    _, info = _delta(p, model, y, wrap=True, route="auto", probes=10)
    assert info["route"] in ("gram", "svd")
    with pytest.raises(ValueError, match=r"needs about .* GB with route 'gram' \(the matrix-free route: "
                                         r".* GB with probes=10\).*batch_size"):
        _delta(p, model, y, wrap=True, route="auto", probes=10, max_jacobian_gb=10e3 / 2**30)
    with pytest.raises(ValueError, match=r"with route 'randomized', above max_jacobian_gb"):
        _delta(p, model, y, route="randomized", probes=10, max_jacobian_gb=10e3 / 2**30)


@pytest.mark.parametrize("kw, match", [(dict(probes=0), r"probes=0.*>= 1"),
                                       (dict(power_iters=-1), r"power_iters=-1.*>= 0"),
                                       (dict(route="lanczos"), r"route='lanczos'.*'randomized'")])
def test_bad_settings(kw, match):
    with pytest.raises(ValueError, match=match):
        HIG(**kw)
