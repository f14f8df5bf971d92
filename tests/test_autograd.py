"""The torch bridge: gradcheck, double backward, forward mode, vmap, Taylor remainder."""

import numpy as np
import pytest
import torch
from exact import load, taylor_rates_through_network
from torch.func import jacrev, jvp, vmap

import pdeinv

SMALL = {
    "heat-steps": ("heat_1d", dict(n=8, steps=5, backend="steps", kappa=0.05)),
    "heat-modal": ("heat_1d", dict(n=8, steps=5, backend="modal", kappa=0.05)),
    "wave": ("wave_1d", dict(n=8, steps=5)),
    "wave_2d": ("wave_2d", dict(n=4, steps=3)),
    "advection": ("advection_diffusion_2d", dict(n=4, steps=4, speed=3.0)),
}


@pytest.fixture(params=list(SMALL))
def op(request):
    name, kw = SMALL[request.param]
    return load(name, **kw).operator


def dense(op):
    return op.forward(np.eye(op.n_in)).T  # column j = P e_j


def test_gradcheck(op):
    x = torch.randn(3, op.n_in, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: pdeinv.apply(op, t), (x,))


def test_gradgradcheck(op):
    x = torch.randn(2, op.n_in, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradgradcheck(lambda t: pdeinv.apply(op, t) ** 2, (x,))


def test_forward_mode_and_vmap_jacobian(op):
    P = torch.from_numpy(dense(op))
    x = torch.randn(op.n_in, dtype=torch.float64)
    v = torch.randn(op.n_in, dtype=torch.float64)
    _, tangent = jvp(lambda t: pdeinv.apply(op, t), (x,), (v,))
    torch.testing.assert_close(tangent, P @ v, rtol=0, atol=1e-12)
    J = jacrev(lambda t: pdeinv.apply(op, t))(x)
    torch.testing.assert_close(J, P, rtol=0, atol=1e-12)
    xs = torch.randn(4, op.n_in, dtype=torch.float64)
    Js = vmap(jacrev(lambda t: pdeinv.apply(op, t)))(xs)
    torch.testing.assert_close(Js, P.expand(4, -1, -1), rtol=0, atol=1e-12)


def test_dtype_and_shape_round_trip():
    op = load("heat_1d", n=8).operator
    x32 = torch.randn(5, op.n_in)
    y = pdeinv.apply(op, x32)
    assert y.dtype == torch.float32 and y.shape == (5, op.n_in)
    ref = op.forward(x32.double().numpy())
    np.testing.assert_allclose(y.numpy(), ref, rtol=1e-5, atol=1e-6)
    assert pdeinv.apply(op, x32[0]).shape == (op.n_in,)


@pytest.mark.parametrize("name, kw", [("heat_1d", dict(n=16, steps=10, kappa=0.02)),
                                      ("advection_diffusion_2d", dict(n=4, steps=5, speed=3.0))])
def test_taylor_remainder_through_network(name, kw):
    """J(θ+εd) − J(θ) − ε∇J·d = O(ε²) for J(θ) = ½‖P f(y; θ) − y*‖² with a tanh MLP."""
    eps = 1e-2 * 0.5 ** np.arange(6)
    rates = taylor_rates_through_network(load(name, **kw), hidden=20, samples=4, eps=eps)
    assert rates.min() >= 1.95, rates


def test_rejects_bad_tensors():
    op = load("heat_1d", n=8).operator
    with pytest.raises(ValueError, match="expected"):
        pdeinv.apply(op, torch.randn(3, op.n_in + 1))
    with pytest.raises(ValueError, match="torch.Tensor"):
        pdeinv.apply(op, np.zeros(op.n_in))
    with pytest.raises(ValueError, match="floating"):
        pdeinv.apply(op, torch.zeros(2, op.n_in, dtype=torch.long))
    bad = torch.zeros(2, op.n_in)
    bad[1, 3] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        pdeinv.apply(op, bad)
