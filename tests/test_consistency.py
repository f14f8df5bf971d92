"""The data-consistency layer (pdeinv.nets.consistency): the observations get back what a correction took,
and nothing outside the operator's spectral basis moves."""

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.nets.consistency import DataConsistency
from pdeinv.physics.capabilities import modal_basis


@pytest.fixture(scope="module")
def boxes():
    """heat_boxes at 12×12 (121 unknowns): a box prior, a modal basis that drops most modes."""
    return pdeinv.load_problem("heat_boxes", n=12)


def _rel_y(p, x, y):
    return float(np.max(p.disc.relative_error(p.operator.forward(x), y)))


def test_the_tikhonov_weights_make_any_estimate_reproduce_noise_free_data(boxes):
    p = boxes
    x, y = p.sample(16, seed=1)
    wrong = x + np.random.default_rng(0).standard_normal(x.shape)  # far from the data
    assert _rel_y(p, wrong, y) > 0.1
    dc = DataConsistency(modal_basis(p.operator), 1e-20)
    fixed = dc(torch.as_tensor(y), torch.as_tensor(wrong)).numpy()
    assert _rel_y(p, fixed, y) < 1e-8


def test_what_the_physics_cannot_see_is_left_alone(boxes):
    """Components of x M-orthogonal to the kept modes (the data's null space) are the estimate's own."""
    p = boxes
    modes = modal_basis(p.operator)
    x, y = p.sample(8, seed=2)
    guess = np.random.default_rng(1).standard_normal(x.shape)
    dc = DataConsistency(modes, 1e-20)
    out = dc(torch.as_tensor(y), torch.as_tensor(guess)).numpy()
    hidden = lambda v: v - (v @ modes.In) @ modes.synth.T  # noqa: E731  (I − Π) in the mass inner product
    np.testing.assert_allclose(hidden(out), hidden(guess), atol=1e-9)
    assert modes.g.size < p.N  # the test means something: there are hidden components


def test_fitted_weights_are_one_noise_free_and_the_wiener_weights_with_noise():
    """Noise-free the data decide every kept mode (w = 1); at 5 % noise the strong modes follow the data and
    the weakest keep the estimate (w falls with g), and the fitted layer beats both on fresh draws."""
    p = pdeinv.load_problem("heat_boxes", n=12)
    modes = modal_basis(p.operator)
    rng = np.random.default_rng(3)
    x, y = p.sample(2000, seed=4)
    guess = x + 0.05 * rng.standard_normal(x.shape) * np.abs(x).max()  # a decent, imperfect estimate
    dc = DataConsistency(modes, 1e-20)
    dc.fit(y, guess, x)
    strong = np.abs(modes.g) > 1e-8 * np.abs(modes.g).max()  # below, d = (y proj)/g carries rounding / g
    assert torch.all(dc.weight[strong] > 1 - 1e-6) and torch.all(dc.weight > 0.99)
    assert _rel_y(p, dc(torch.as_tensor(y), torch.as_tensor(guess)).numpy(), y) < 1e-8

    q = pdeinv.load_problem("heat_boxes", n=12, noise=0.05)
    x, y = q.sample(4000, seed=5)
    guess = x + 0.05 * rng.standard_normal(x.shape) * np.abs(x).max()
    dc = DataConsistency(modes, 0.05**2)
    dc.fit(y[:3000], guess[:3000], x[:3000])
    w, g = dc.weight.numpy(), np.abs(modes.g)
    assert w[np.argmax(g)] > 0.9 and w[np.argmin(g)] < 0.1
    out = dc(torch.as_tensor(y[3000:]), torch.as_tensor(guess[3000:])).numpy()
    err = lambda a: float(np.mean(q.relative_error(a, x[3000:])))  # noqa: E731
    data_only = DataConsistency(modes, 1e-20)(torch.as_tensor(y[3000:]), torch.as_tensor(guess[3000:]))
    assert err(out) < err(guess[3000:]) and err(out) < err(data_only.numpy())


def test_the_layer_is_float64_and_saves_only_its_weights(boxes):
    dc = DataConsistency(modal_basis(boxes.operator), 1e-20).float()
    assert dc.weight.dtype == torch.float64
    assert set(dc.state_dict()) == {"weight"}


def test_the_rule_keeps_the_modes_the_data_resolve(boxes):
    """With the rule's estimate ``b``, the modes with ``g² ≥ α`` are b's to rounding, the other kept modes
    are the data blend's, and what the physics cannot see is the estimate's own."""
    p = boxes
    modes = modal_basis(p.operator)
    rng = np.random.default_rng(5)
    x, y = p.sample(8, seed=6)
    guess, base = (torch.as_tensor(rng.standard_normal(x.shape)) for _ in range(2))
    dc = DataConsistency(modes, 1e-4)  # 1 % noise: α = 1e-4 max g²
    r = dc.resolved.numpy()
    np.testing.assert_array_equal(r, modes.g**2 >= 1e-4 * np.max(modes.g**2))
    assert 0 < r.sum() < r.size  # both kinds of mode exist
    out, blend = dc(torch.as_tensor(y), guess, base).numpy(), dc(torch.as_tensor(y), guess).numpy()
    coef = lambda v: np.asarray(v) @ modes.In  # noqa: E731
    np.testing.assert_allclose(coef(out)[:, r], coef(base)[:, r], atol=1e-9)
    np.testing.assert_allclose(coef(out)[:, ~r], coef(blend)[:, ~r], atol=1e-9)
    hidden = lambda v: np.asarray(v) - coef(v) @ modes.synth.T  # noqa: E731
    np.testing.assert_allclose(hidden(out), hidden(guess), atol=1e-9)
    dc.weight[np.flatnonzero(r)[-1]] = 0.2  # a fit found the corrected estimate better there: not the rule's
    kept = r.copy()
    kept[np.flatnonzero(r)[-1]] = False
    out, blend = dc(torch.as_tensor(y), guess, base).numpy(), dc(torch.as_tensor(y), guess).numpy()
    np.testing.assert_allclose(coef(out)[:, kept], coef(base)[:, kept], atol=1e-9)
    np.testing.assert_allclose(coef(out)[:, ~kept], coef(blend)[:, ~kept], atol=1e-9)
