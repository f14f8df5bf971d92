"""HIG on dense networks (MLPs): the last-layer route (pdeinv.methods.hig.layers) takes the exact step of
the last layer; the dense routes build J from the layer structure (pdeinv.methods.hig.structured)."""

import copy
import warnings

import pytest
import torch
from torch import nn

import pdeinv
from pdeinv import nets
from pdeinv.methods import HIG

pytestmark = pytest.mark.usefixtures("one_thread")


def problem():
    return pdeinv.load_problem("heat_1d", n=16, steps=10)


def freeze_hidden(model):
    linears = [m for m in model.modules() if isinstance(m, nn.Linear)]
    for m in linears[:-1]:
        for p in m.parameters():
            p.requires_grad_(False)
    return model


def random_last_layer(model):
    """A nonzero last layer, so that the hidden layers' Jacobian is not zero either."""
    last = [m for m in model.modules() if isinstance(m, nn.Linear)][-1]
    with torch.no_grad():
        last.weight.normal_(std=0.1)
    return model


def one_linear(p):
    return random_last_layer(nets.dense(p.operator.n_out, p.operator.n_in, ()).double())


def mlp(p, hidden=(8, 8)):
    model = nets.MLP(p.operator.n_out, p.operator.n_in, hidden).double()
    _, y = p.sample(64, seed=1)
    return random_last_layer(model.fit_input_scaling(torch.as_tensor(y)))


def decoded_mlp(p):
    model = nets.reduced(k_in=10, k_out=9, body="mlp", hidden=(6,))(p)
    _, y = p.sample(64, seed=1)
    nets.fit_preconditioning(model, y)
    return random_last_layer(model)


MODELS = {  # name -> model factory: the networks whose exact HIG step the route takes
    "one linear": one_linear,
    "mlp, hidden frozen": lambda p: freeze_hidden(mlp(p)),
    "dense, hidden frozen": lambda p: freeze_hidden(random_last_layer(
        nets.dense(p.operator.n_out, p.operator.n_in, (5,)).double())),
    "prior decoder, hidden frozen": lambda p: freeze_hidden(decoded_mlp(p)),
}


def steps(p, model, routes, tau, batch=8):
    _, y = p.sample(batch, seed=2)
    Y = torch.as_tensor(y, dtype=torch.float64)
    out = {}
    for route in routes:
        rule = HIG(eta=0.7, tau=tau, route=route)
        out[route] = rule.update(rule.init(p, model), model, Y)
    return out


def close(a, b, rel):
    scale = max(float(d.abs().max()) for d in a)
    assert scale > 0
    for x, z in zip(a, b, strict=True):
        assert x.shape == z.shape
        assert float((x - z).abs().max()) <= rel * scale


@pytest.mark.parametrize("name", sorted(MODELS))
@pytest.mark.parametrize("tau", [1e-7, 1e-2])
def test_with_one_trainable_layer_the_route_is_the_exact_dense_step(name, tau):
    """Only the last layer trainable: J is J_L, exactly Kronecker, so the route's step is HIG's exact one
    (the dense SVD route), normalization and τ drop included (float64; 1e-7 relative: the kept
    condition number reaches 1e7 at τ = 1e-7, as in tests/test_hig_kron.py)."""
    p = problem()
    out = steps(p, MODELS[name](p), ("svd", "last_layer"), tau)
    dense, ours = out["svd"], out["last_layer"]
    assert ours.info["route"] == "last_layer" and dense.info["route"] == "svd"
    assert ours.info["loss"] == pytest.approx(dense.info["loss"], rel=1e-12)
    assert ours.info["sigma_max"] == pytest.approx(dense.info["sigma_max"], rel=1e-10)
    assert ours.info["kept"] == dense.info["rank"]
    close(dense.direction, ours.direction, 1e-7)


@pytest.mark.parametrize("tau", [1e-7, 1e-2])
def test_the_last_layer_takes_the_exact_kronecker_step_on_the_hidden_features(tau):
    """All layers trainable: the last layer's part is hig_kron's exact step with the hidden features as
    Z̃ (the dense SVD route of the same network with its hidden layers frozen) and the hidden layers
    take none. The dense route on the whole network differs (its J has the hidden blocks too)."""
    p = problem()
    model = mlp(p)
    ours = steps(p, model, ("last_layer", "svd"), tau)
    exact_last = steps(p, freeze_hidden(copy.deepcopy(model)), ("svd",), tau)["svd"]
    names = [n for n, _ in model.named_parameters()]
    parts = list(zip(names, ours["last_layer"].direction, strict=True))
    hidden = [d for n, d in parts if not n.startswith("body.4")]
    last = [d for n, d in parts if n.startswith("body.4")]
    assert len(hidden) == 4 and all(float(d.abs().max()) == 0.0 for d in hidden)
    close(exact_last.direction, last, 1e-7)
    whole = ours["svd"].direction[-2:]
    assert float((whole[0] - last[0]).abs().max()) > 1e-3 * float(whole[0].abs().max())


def test_other_networks_are_refused_naming_what_is_supported():
    p = problem()
    _, y = p.sample(4, seed=1)
    Y = torch.as_tensor(y, dtype=torch.float64)
    residual = nets.whitened("residual", hidden=(4,))(p)
    nets.fit_preconditioning(residual, p.sample(64, seed=1)[1])
    odd = nn.Sequential(nn.Linear(p.operator.n_out, 4), nn.LayerNorm(4), nn.Linear(4, p.operator.n_in))
    for model, why in ((residual, "Residual"), (odd, "LayerNorm")):
        rule = HIG(route="last_layer")
        with pytest.raises(ValueError, match=f"supports pdeinv.MLP.*{why}"):
            rule.update(rule.init(p, model), model, Y)
    frozen = mlp(p)
    for q in frozen.body[-1].parameters():
        q.requires_grad_(False)
    rule = HIG(route="last_layer")
    with pytest.raises(ValueError, match="last nn.Linear layer only"):
        rule.update(rule.init(p, frozen), frozen, Y)


@pytest.mark.parametrize("scene, settings, factor", [("heat_1d", dict(n=32, steps=10), 1.0),
                                                     ("wave_1d", dict(n=32), 2.5)])
def test_the_route_is_about_as_accurate_as_the_dense_route_at_a_tenth_of_its_steps(scene, settings, factor):
    """The CLI's HIG preset on an MLP (16, 16), batch 32, the same data and seed: the last-layer route
    after 100 steps (~0.3 s) against the default route (the exact step: the dense Jacobian's Gram) after 10
    (a few seconds, one shared thread). Measured x-errors: heat_1d 0.206 against 0.254 (better), wave_1d
    0.209 against 0.105 (2.0× worse: a narrow MLP's fixed random features limit the route where
    the hidden layers matter); the factors leave ~20 % margin, and the test fails if either route's
    accuracy moves past them."""
    import dataclasses

    from pdeinv.methods.presets import make_rule

    p = pdeinv.load_problem(scene, **settings)
    errs = {}
    for route, steps in (("auto", 10), ("last_layer", 100)):
        rule, hp = make_rule("hig", p, hidden=(16, 16))
        torch.manual_seed(0)
        model = nets.MLP(p.operator.n_out, p.operator.n_in, (16, 16))
        r = pdeinv.Trainer(p, dataclasses.replace(rule, route=route), model, steps=steps, n_train=128,
                           n_test=64, batch_size=hp["batch_size"], seed=0, progress=False,
                           eval_every=steps, prior=None).fit()
        errs[route] = r.metrics["x_err"]
        assert r.history[-1]["route"] == ("last_layer" if route == "last_layer" else "gram")
    assert errs["last_layer"] < factor * errs["auto"], errs


STRUCTURED = {  # name -> model factory: dense networks whose J the dense routes build from the layers
    "mlp": mlp,
    "mlp, first layer frozen": lambda p: freeze_first(mlp(p)),
    "dense relu, no bias": lambda p: random_last_layer(nn.Sequential(
        nn.Linear(p.operator.n_out, 6, bias=False), nn.ReLU(),
        nn.Linear(6, p.operator.n_in, bias=False)).double()),
    "prior decoder": decoded_mlp,
}


def freeze_first(model):
    for q in [m for m in model.modules() if isinstance(m, nn.Linear)][0].parameters():
        q.requires_grad_(False)
    return model


@pytest.mark.parametrize("name", sorted(STRUCTURED))
@pytest.mark.parametrize("route, tau, rel", [("svd", 1e-7, 1e-7), ("gram", 1e-2, 1e-9), ("auto", 1e-7, 1e-7)])
def test_the_structured_jacobian_gives_the_torch_func_step(name, route, tau, rel, monkeypatch):
    """J (or J Jᵀ) from the layer structure: the same step as the Jacobian of torch.func, every layer
    trainable or some frozen, with and without a decoder, in float64 (1e-7 relative: the kept
    condition number reaches 1e7 at τ = 1e-7; the Gram at τ = 1e-2, where its squared condition number
    does not amplify the two Jacobians' rounding differences past 1e-9)."""
    from pdeinv.methods.hig import routes as hig_routes

    p = problem()
    model = STRUCTURED[name](p)
    ours = steps(p, model, (route,), tau)[route]
    monkeypatch.setattr(hig_routes, "_structured", lambda rule, b: None)
    ref = steps(p, model, (route,), tau)[route]
    assert ours.info["jacobian"] == "structured" and ref.info["jacobian"] in ("reverse", "forward")
    assert ours.info["route"] == ref.info["route"] and ours.info["rank"] == ref.info["rank"]
    assert ours.info["sigma_max"] == pytest.approx(ref.info["sigma_max"], rel=1e-12)
    close(ref.direction, ours.direction, rel)


def test_other_networks_keep_the_torch_func_jacobian():
    p = problem()
    model = nets.whitened("residual", hidden=(4,))(p)
    nets.fit_preconditioning(model, p.sample(64, seed=1)[1])
    assert steps(p, model, ("auto",), 1e-6)["auto"].info["jacobian"] in ("reverse", "forward")


def test_auto_over_the_jacobian_budget_says_only_the_last_layer_trains():
    """``route="auto"`` whose dense J does not fit takes the last-layer route with a warning naming it,
    never silently (a review found the hidden layers frozen without a word)."""
    p = problem()
    model = MODELS["dense, hidden frozen"](p)
    for q in model.parameters():
        q.requires_grad_(True)
    _, y = p.sample(8, seed=2)
    rule = HIG(route="auto", max_jacobian_gb=1e-5)
    with pytest.warns(UserWarning, match="only the last layer trains"):
        out = rule.update(rule.init(p, model), model, torch.as_tensor(y, dtype=torch.float64))
    assert out.info["route"] == "last_layer"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rule = HIG(route="auto")  # within the budget: the dense route, no warning
        assert rule.update(rule.init(p, model), model, torch.as_tensor(y, dtype=torch.float64)).info[
            "route"] != "last_layer"
