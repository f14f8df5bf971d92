"""Supervised training on the true fields through the common trainer (a rule and a target)."""

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.methods.presets import make_rule
from pdeinv.methods.targets import TrueFields


def test_supervised_fits_the_true_fields_and_reports_the_y_loss():
    """The preset (full-batch SGD at lr 1 on the whitened map) is the least-squares fit of x on the whitened
    y in one step: its x-loss does not move after it, and the fit is the empirical linear MMSE of the
    training pairs (heat_1d: x_err measured 0.0026 after 10 steps; SIP 0.0040)."""
    p = pdeinv.load_problem("heat_1d")
    rule, hp = make_rule("supervised", p)
    res = pdeinv.train(p, rule, steps=hp["steps"], batch_size=hp["batch_size"], seed=0, progress=False,
                       prior=None)
    assert res.metrics["target"] == {"name": "true_fields", "rows": 1024}
    xs = [h["x_loss"] for h in res.history if "x_loss" in h]
    assert xs[1] < 1e-4 * xs[0] and abs(xs[-1] - xs[1]) <= 1e-6 * xs[0]
    assert res.metrics["x_err"] < 0.005 and all(np.isfinite(h["loss"]) for h in res.history)


def test_supervised_direction_is_the_gradient_of_the_x_loss():
    p = pdeinv.load_problem("heat_1d", n=16)
    net = pdeinv.nets.whitened("linear")(p)
    x, y = p.sample(8, 0)
    net.fit_observations(y)
    with torch.no_grad():
        for q in net.parameters():
            q.normal_(0, 0.1)
    rule = pdeinv.Supervised(normalize=False)
    yt, xt = torch.as_tensor(y), torch.as_tensor(x)
    up = rule.update(rule.init(p, net), net, yt, xt)
    loss = 0.5 * ((net(yt) - xt) ** 2).sum(-1).mean()
    expected = torch.autograd.grad(loss, list(net.parameters()))
    for d, e in zip(up.direction, expected, strict=True):
        assert torch.allclose(d, e, rtol=1e-12, atol=1e-14)
    assert up.info["loss"] == pytest.approx(0.5 * ((p.operator.forward(net(yt).detach().numpy()) - y) ** 2)
                                            .sum(-1).mean(), rel=1e-12)


def test_supervised_without_x_is_refused_naming_x():
    p = pdeinv.load_problem("heat_1d")
    _, y = p.sample(100, 0)
    with pytest.raises(ValueError, match="needs the training rows' x"):
        pdeinv.train(p, pdeinv.Supervised(), data=y, n_test=20, steps=1, progress=False, prior=None)
    with pytest.raises(ValueError, match="true fields"):
        pdeinv.Supervised().update(None, torch.nn.Linear(2, 2), torch.zeros(1, 2))
    assert TrueFields().fit(p, y[:3], None, fields=lambda: y[:3]).info["rows"] == 3
