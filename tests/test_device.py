"""Physics on a torch device (:mod:`pdeinv.physics.backends.device`): the dense, modal and SVD matmuls in
torch.

The CUDA path is the torch path of :class:`~pdeinv.physics.backends.device.Placed` with another
device, so it is checked here on the CPU: agreement with the numpy backend to 1e-12, the
dot-product identity, ``gradcheck`` in float64 through the autograd bridge, no numpy call on
the way, and a training run equal to the numpy one. The CUDA tests run only where CUDA is.
"""

import dataclasses

import numpy as np
import pytest
import torch
from exact import load

import pdeinv
from pdeinv.physics.backends.device import Placed, placed, resolve

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")

#: (scene, settings): a modal heat, a dense and an SVD wave with sensors (records, not a field)
CASES = {
    "heat-modal": ("heat_1d", dict(n=16, steps=10, backend="modal")),
    "heat-dense": ("heat_1d", dict(n=16, steps=10, backend="dense")),
    "sensors-svd": ("wave_sensors_2d", dict(n=4, steps=6, record_every=2, sensors=3, backend="svd")),
    "sensors-dense": ("wave_sensors_2d", dict(n=4, steps=6, record_every=2, sensors=3, backend="dense")),
}


def _op(case):
    name, kw = CASES[case]
    return load(name, **kw).operator


def _rel(a, b) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("case", sorted(CASES))
def test_torch_apply_agrees_with_numpy_and_is_its_exact_transpose(case):
    op = _op(case)
    dev = Placed(op, "cpu")
    rng = np.random.default_rng(1)
    X, R = rng.standard_normal((5, op.n_in)), rng.standard_normal((5, op.n_out))
    Y = dev.torch_forward(torch.from_numpy(X)).numpy()
    XT = dev.T.torch_forward(torch.from_numpy(R)).numpy()
    assert _rel(Y, op.forward(X)) <= 1e-12
    assert _rel(XT, op.adjoint(R)) <= 1e-12
    lhs, rhs = np.sum(Y * R), np.sum(X * XT)  # ⟨P x, r⟩ = ⟨x, Pᵀ r⟩
    assert abs(lhs - rhs) <= 1e-12 * max(abs(lhs), abs(rhs))


@pytest.mark.parametrize("case", ["heat-modal", "sensors-svd"])
def test_bridge_gradcheck_through_the_torch_apply(case):
    dev = Placed(_op(case), "cpu")
    x = torch.randn(2, dev.n_in, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: pdeinv.apply(dev, t), (x,))
    assert torch.autograd.gradgradcheck(lambda t: pdeinv.apply(dev, t), (x,))


def test_the_torch_path_never_calls_numpy(monkeypatch):
    op = _op("heat-modal")
    dev = Placed(op, "cpu")
    x = torch.randn(3, op.n_in, dtype=torch.float64, requires_grad=True)
    want = pdeinv.apply(op, x).detach()

    def refuse(*_):
        raise AssertionError("the numpy backend was called")

    monkeypatch.setattr(op.backend, "forward", refuse)
    monkeypatch.setattr(op.backend, "adjoint", refuse)
    y = pdeinv.apply(dev, x)
    y.pow(2).sum().backward()
    assert torch.allclose(y.detach(), want, rtol=1e-12, atol=0)
    assert x.grad is not None and bool(torch.isfinite(x.grad).all())


def test_a_placed_operator_keeps_the_capabilities_of_its_own():
    op = _op("heat-modal")
    dev = Placed(op, "cpu")
    assert dev.modes is op.modes and dev.output_space == op.output_space and dev.T.T.n_in == op.n_in


def test_time_stepping_has_nothing_to_place():
    op = load("heat_1d", n=16, steps=10, backend="steps").operator
    with pytest.raises(ValueError, match="no dense, modal or SVD backend"):
        Placed(op, "cpu")
    problem = load("heat_1d", n=16, steps=10, backend="steps")
    assert placed(problem, "cpu") is problem


def test_training_with_the_torch_apply_equals_the_numpy_one():
    problem = load("heat_1d", n=16, steps=10, backend="modal")
    on_torch = dataclasses.replace(problem, operator=Placed(problem.operator, "cpu"))
    runs = []
    for p in (problem, on_torch):
        torch.manual_seed(0)
        runs.append(pdeinv.train(p, pdeinv.GD(), steps=8, n_train=32, n_test=8, batch_size=8,
                                 eval_every=4, dtype=torch.float64, prior=None))
    a, b = ([h["loss"] for h in r.history] for r in runs)
    assert np.allclose(a, b, rtol=1e-10, atol=0) and runs[0].metrics["x_err"] == pytest.approx(
        runs[1].metrics["x_err"], rel=1e-10)


@pytest.mark.parametrize("device", ["cuda:99", "gpu", "mps"])
def test_resolve_refuses_devices_that_are_not_here(device):
    with pytest.raises(ValueError, match=repr(device)):
        resolve(device)
    with pytest.raises(ValueError, match=repr(device)):
        pdeinv.Trainer(load("heat_1d", n=16, steps=10), pdeinv.GD(), steps=1, device=device, prior=None)


def test_resolve_accepts_the_cpu():
    assert resolve("cpu") == torch.device("cpu")


@CUDA
@pytest.mark.parametrize("case", sorted(CASES))
def test_cuda_apply_agrees_with_numpy(case):
    op = _op(case)
    dev = Placed(op, "cuda")
    X = torch.randn(4, op.n_in, dtype=torch.float64, device="cuda", requires_grad=True)
    Y = pdeinv.apply(dev, X)
    assert Y.device.type == "cuda"
    assert _rel(Y.detach().cpu().numpy(), op.forward(X.detach().cpu().numpy())) <= 1e-12
    Y.sum().backward()
    assert _rel(X.grad.cpu().numpy(), op.adjoint(np.ones((4, op.n_out)))) <= 1e-12


@CUDA
def test_cuda_training_matches_the_cpu():
    problem = load("heat_1d", n=16, steps=10, backend="modal")
    runs = [pdeinv.train(problem, pdeinv.GD(), steps=8, n_train=32, n_test=8, batch_size=8, eval_every=4,
                         dtype=torch.float64, device=d, seed=0, prior=None) for d in ("cpu", "cuda")]
    assert runs[1].metrics["device"].startswith("cuda")
    assert runs[1].metrics["x_err"] == pytest.approx(runs[0].metrics["x_err"], rel=1e-8)
