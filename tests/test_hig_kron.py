"""HIG's Kronecker route (pdeinv.methods.hig.kron) equals the dense SVD route, without forming J."""

import math

import pytest
import torch
from torch import nn

import pdeinv
from pdeinv import nets
from pdeinv.methods import HIG
from pdeinv.nets.whitening import Whitening

pytestmark = pytest.mark.usefixtures("one_thread")


def net_without_bias(problem):
    m, n = problem.operator.n_out, problem.operator.n_in
    return nets.Net(Whitening(m), nn.Linear(m, n, bias=False)).double()


CASES = {  # name -> (scene, settings, model factory)
    "heat_1d": ("heat_1d", dict(n=16, steps=10), nets.whitened("linear")),
    "no-bias": ("heat_1d", dict(n=16, steps=10), net_without_bias),
    "sensors": ("heat_sensors_2d", dict(n=6, sensors=7), nets.whitened("linear")),
    "advection": ("advection_diffusion_2d", dict(n=6), nets.whitened("linear")),
    "wave": ("wave_1d", dict(n=16), nets.whitened("linear")),
    "reduced": ("heat_2d", dict(n=8), nets.reduced(k_in=12, k_out=9)),
    # one whitened direction per 8 rows: the trailing feature columns are zero on every row ("dead")
    "dead": ("wave_1d", dict(n=16), nets.whitened("linear", rows_per_component=8)),
}


def directions(case, tau, batch=8):
    p, model, _ = full_batch(case)
    _, y = p.sample(batch, seed=2)
    Y = torch.as_tensor(y, dtype=torch.float64)
    out = {}
    for route in ("svd", "kronecker"):
        rule = HIG(eta=0.7, tau=tau, route=route)
        out[route] = rule.update(rule.init(p, model), model, Y)
    return out


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("tau", [1e-7, 1e-2])
def test_kronecker_route_equals_the_dense_svd_route(case, tau):
    out = directions(case, tau)
    dense, kron = out["svd"], out["kronecker"]
    assert kron.info["route"] == "kronecker"
    assert kron.info["loss"] == pytest.approx(dense.info["loss"], rel=1e-12)
    scale = max(float(d.abs().max()) for d in dense.direction)
    for a, b in zip(dense.direction, kron.direction, strict=True):
        assert a.shape == b.shape
        assert float((a - b).abs().max()) < 1e-7 * scale, (case, tau)


def test_tau_drops_directions():
    few, many = directions("heat_1d", 1e-2)["kronecker"], directions("heat_1d", 1e-7)["kronecker"]
    assert 0 < few.info["kept"] < many.info["kept"]
    assert few.info["sigma_min_kept"] > 1e-2 * few.info["sigma_max"]


def test_a_network_not_linear_in_theta_cannot_take_the_route():
    p = pdeinv.load_problem("heat_1d", n=16, steps=10)
    with pytest.raises(ValueError, match="linear in its parameters"):
        HIG(route="kronecker").init(p, nets.whitened("mlp", hidden=(8,))(p))
    rule = HIG()  # auto: the dense route for the MLP
    model = nets.whitened("mlp", hidden=(8,))(p)
    _, y = p.sample(64, seed=1)
    nets.fit_preconditioning(model, y)
    assert rule.update(rule.init(p, model), model, torch.as_tensor(y[:4])).info["route"] != "kronecker"


@pytest.mark.parametrize("scene, settings", [("heat_1d", dict(n=32, steps=10)), ("wave_1d", dict(n=32))])
def test_hig_defaults_beat_adam_defaults_at_equal_steps(scene, settings):
    """The CLI presets (methods/presets.py), 50 steps each, same data: HIG's exact Kronecker step on
    the default network against Adam's (measured: heat_1d 0.028 vs 0.86, wave_1d 8e-9 vs 0.81)."""
    from pdeinv.methods.presets import make_rule

    p = pdeinv.load_problem(scene, **settings)
    errs = {}
    for method in ("hig", "adam"):
        rule, hp = make_rule(method, scene)
        torch.manual_seed(0)
        r = pdeinv.Trainer(p, rule, steps=50, n_train=256, n_test=64, batch_size=hp["batch_size"], seed=0,
                           progress=False, eval_every=50, prior=None).fit()
        errs[method] = r.metrics["x_err"]
        if method == "hig":
            assert r.history[-1]["route"] == "kronecker"
    assert errs["hig"] < 0.5 * errs["adam"], errs


def test_input_gram_reuses_its_eigenpairs_for_the_same_rows_in_any_order():
    """The full batch reshuffled: the kept Gram (recognized by the rows' bytes, not formed again) and
    its eigenpairs; other rows: a new decomposition that agrees with numpy's."""
    import numpy as np

    from pdeinv.methods.hig import kron as hig_kron

    rng = np.random.default_rng(0)
    y = torch.as_tensor(rng.standard_normal((40, 6)))
    Z = y.numpy() * np.arange(1, 7)
    gram = hig_kron.InputGram()
    key = hig_kron.rows_key(y)
    assert gram.kept(key) is None
    a, W = gram(Z.T @ Z, key)
    perm = torch.randperm(40)
    assert hig_kron.rows_key(y[perm]) == key and gram.kept(hig_kron.rows_key(y[perm])) is gram.G
    a2, W2 = gram(gram.kept(key), key)
    assert a2 is a and W2 is W
    half = hig_kron.rows_key(y[:20])
    assert gram.kept(half) is None
    a3, _ = gram(Z[:20].T @ Z[:20], half)
    assert np.allclose(a3, np.linalg.eigvalsh(Z[:20].T @ Z[:20]), rtol=1e-12) and not np.allclose(a3, a)


@pytest.mark.parametrize("rows", [5, 40])
def test_the_batch_side_gram_equals_the_feature_side_gram(rows):
    """A minibatch decomposes A = Z̃Z̃ᵀ (B × B), the full batch G = Z̃ᵀZ̃ (k̃ × k̃): the same step, fewer or
    more rows than features, with τ dropping directions."""
    import numpy as np

    from pdeinv.inverse.decoder import DecodedSVD
    from pdeinv.methods.hig import kron as hig_kron

    rng = np.random.default_rng(3)
    k, m, r = 12, 9, 6
    Z = np.hstack([rng.standard_normal((rows, k)) * np.logspace(0, -3, k), np.ones((rows, 1))])
    Q = np.linalg.qr(rng.standard_normal((m, r)))[0]
    fac = DecodedSVD(Q, np.logspace(0, -4, r), np.linalg.qr(rng.standard_normal((7, r)))[0])
    R = rng.standard_normal((rows, m))
    for tau in (0.0, 1e-3):
        G, N = hig_kron.moments(fac, Z, R)
        a, info_a = hig_kron.direction(fac, G, N, rows, 0.7, tau, -0.5)
        b, info_b = hig_kron.direction_rows(fac, Z, R, 0.7, tau, -0.5)
        assert info_a["kept"] == info_b["kept"] and info_a["sigma_max"] == pytest.approx(info_b["sigma_max"])
        assert np.abs(a - b).max() < 1e-9 * np.abs(a).max(), (rows, tau)



@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("tau", [1e-7, 1e-2])
def test_the_same_rows_again_take_the_kept_part_of_the_step(case, tau):
    """The full batch again, reshuffled, with targets other than the observations: the step from the
    kept rows (no feature map, no physics: hig_fixed) equals the step a fresh rule computes from the
    batch, direction and loss, to float64 rounding; other rows are not mistaken for them."""
    p, model, Y = full_batch(case)
    goal = 0.9 * Y + 0.01 * torch.randn_like(Y)
    rule = HIG(eta=0.7, tau=tau, route="kronecker")
    state = rule.init(p, model)
    rule.update(state, model, Y, goal)
    perm = torch.randperm(len(Y))
    kept = rule.update(state, model, Y[perm], goal[perm])
    assert state.context[-1].seen["carried"].M is not None  # the kept route was taken
    direct = fresh_step(p, model, Y[perm], goal[perm], tau)
    assert kept.info["loss"] == pytest.approx(direct.info["loss"], rel=1e-9)
    assert kept.info["kept"] == direct.info["kept"]
    close(kept.direction, direct.direction, 1e-7, case)
    other = rule.update(state, model, Y[:40], goal[:40])  # new rows: computed from the batch
    assert other.info["loss"] == pytest.approx(fresh_step(p, model, Y[:40], goal[:40], tau).info["loss"],
                                               rel=1e-9)


@pytest.mark.parametrize("float32", [False, True])
@pytest.mark.parametrize("moved", ["applied", "scaled", "rolled back", "edited"])
def test_the_carried_residual_follows_the_weights(moved, float32, monkeypatch):
    """Between refreshes the residual M is carried through each applied step c·ΔW̃ (a guard's
    multiplier c, 0 for a rejected step); weights moved otherwise are recomputed. Each way, the next
    step equals a fresh rule's at the same weights: to float64 rounding, or to 1e-5 with the float32
    products of large scenes (hig_fixed.FLOAT32_ABOVE)."""
    from pdeinv.methods.hig import fixed as hig_fixed

    if float32:
        monkeypatch.setattr(hig_fixed, "FLOAT32_ABOVE", 0)
    rel = 1e-5 if float32 else 1e-9
    p, model, Y = full_batch("heat_1d")
    rule = HIG(eta=0.7, tau=1e-7, route="kronecker")
    state = rule.init(p, model)
    rule.update(state, model, Y)
    params = list(model.parameters())
    u = rule.update(state, model, Y)
    c = {"applied": 1.0, "scaled": 0.25, "rolled back": 0.0, "edited": 1.0}[moved]
    with torch.no_grad():
        for q, d in zip(params, u.direction, strict=True):
            q.add_(c * d)
        if moved == "edited":
            params[0][0, 0] += 0.05
    carried = state.context[-1].seen["carried"]
    age = carried.age
    nxt = rule.update(state, model, Y)
    assert carried.age == (0 if moved == "edited" else age + 1)
    fresh = fresh_step(p, model, Y, Y, 1e-7)
    close(nxt.direction, fresh.direction, rel, moved)
    assert nxt.info["loss"] == pytest.approx(fresh.info["loss"], rel=rel)


def full_batch(case):
    """``(problem, model, its 64 training rows)``: the model whitened on them, with a nonzero random W
    (the residual then has every part)."""
    scene, settings, factory = CASES[case]
    p = pdeinv.load_problem(scene, **settings)
    model = factory(p)
    _, y_train = p.sample(64, seed=1)
    nets.fit_preconditioning(model, y_train)
    torch.manual_seed(0)
    with torch.no_grad():
        for q in model.parameters():
            q.normal_(0, 0.1)
    return p, model, torch.as_tensor(y_train, dtype=torch.float64)


def fresh_step(p, model, y, goal, tau):
    rule = HIG(eta=0.7, tau=tau, route="kronecker")
    return rule.update(rule.init(p, model), model, y, goal)


def close(got, want, rel, what):
    scale = max(float(d.abs().max()) for d in want)
    for a, b in zip(want, got, strict=True):
        assert a.shape == b.shape
        assert float((a - b).abs().max()) < rel * scale, what


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("scene", ["heat_1d", "wave_1d"])
def test_hig_on_cuda_matches_the_cpu(scene):
    """The Kronecker route (and its kept-rows form) on a CUDA model: the same run as on the CPU."""
    problem = pdeinv.load_problem(scene, n=16)
    runs = [pdeinv.train(problem, HIG(), steps=6, n_train=64, n_test=8, batch_size=None, eval_every=3,
                         dtype=torch.float64, device=d, seed=0, prior=None) for d in ("cpu", "cuda")]
    assert runs[1].metrics["device"].startswith("cuda")
    assert runs[1].metrics["x_err"] == pytest.approx(runs[0].metrics["x_err"], rel=1e-8)


def test_the_hig_preset_batch_is_every_row_on_the_default_networks_and_32_on_an_mlp():
    """The Kronecker route sums the rows once, so the full batch costs one step; an MLP's dense stacked
    Jacobian grows with the batch (presets.HIG_MLP_BATCH); a batch the user gives is kept."""
    from pdeinv.methods.presets import HIG_MLP_BATCH, hyperparameters

    assert hyperparameters("hig", "heat_2d")["batch_size"] is None
    assert hyperparameters("hig", "heat_2d", hidden=(16,))["batch_size"] == HIG_MLP_BATCH == 32
    assert hyperparameters("hig", "heat_2d", hidden=(16,), batch_size=4)["batch_size"] == 4
    assert hyperparameters("sip", "heat_2d")["batch_size"] is None  # SIP on an MLP: test_accuracy


def test_dead_feature_columns_get_no_step_and_a_smaller_product():
    """Feature columns zero on every row (directions the whitening dropped) have zero Jacobian columns:
    the kept-rows step leaves their weights alone exactly and decomposes the live columns only."""
    p, model, Y = full_batch("dead")
    rule = HIG(eta=0.7, tau=1e-7, route="kronecker")
    state = rule.init(p, model)
    rule.update(state, model, Y)
    step = rule.update(state, model, Y)
    fixed = state.context[-1].seen["carried"].fixed
    lin = model.linear_in_parameters()
    dead = torch.as_tensor(lin.features(Y).abs().amax(0) == 0)
    live = set(torch.nonzero(~dead).ravel().tolist()) | {lin.layer.in_features}  # and the bias
    assert 0 < int(dead.sum()) and set(fixed.cols.tolist()) <= live and fixed.A1.shape[-1] == len(fixed.cols)
    weight = step.direction[0]
    assert bool((weight[:, dead] == 0).all()) and float(weight[:, ~dead].abs().max()) > 0


@pytest.mark.parametrize("dead", [0, 3])
def test_uncorrelated_features_take_a_diagonal_gram_and_the_same_step(dead, monkeypatch):
    """Features uncorrelated to rounding (a whitening with a noise floor, fitted on these rows): W = I, the
    second product a column scaling; the step, the loss and the carried residual equal the eigenbasis
    route's, with dead columns and τ dropping directions."""
    import numpy as np

    from pdeinv.inverse.decoder import DecodedSVD
    from pdeinv.methods.hig import fixed as hig_fixed

    rng = np.random.default_rng(5)
    rows, k, m, r, out = 40, 9, 8, 6, 7
    centred = rng.standard_normal((rows, k))
    centred -= centred.mean(0)  # orthogonal to the bias column
    Z = np.hstack([np.linalg.qr(centred)[0] * np.logspace(0, -4, k), np.ones((rows, 1))])
    Z[:, k - dead:k] = 0.0
    fac = DecodedSVD(np.linalg.qr(rng.standard_normal((m, r)))[0], np.logspace(0, -3, r),
                     np.linalg.qr(rng.standard_normal((out, r)))[0])
    goal = rng.standard_normal((rows, m))
    weight = rng.standard_normal((out, k + 1))
    G = Z.T @ Z
    steps = {}
    for diagonal in (True, False):
        monkeypatch.setattr(hig_fixed, "UNCORRELATED", 1e-10 if diagonal else -1.0)
        fixed = hig_fixed.FixedRows.of(fac, Z, goal, *np.linalg.eigh(G), 1e-3, -0.5)
        assert (fixed.A1.ndim == 1) == diagonal and len(fixed.cols) == k + 1 - dead
        carried = hig_fixed.Carried(fixed)
        first, loss = carried.step(weight.copy(), 0.7, 1.0)
        nxt = weight + 0.5 * first
        second, loss2 = carried.step(nxt.copy(), 0.7, 1.0)  # carried: M + 0.5·ΔM
        assert carried.age == 1
        steps[diagonal] = (first.copy(), loss, second.copy(), loss2)
    for a, b in zip(steps[True], steps[False], strict=True):
        assert np.abs(np.asarray(a) - np.asarray(b)).max() <= 1e-10 * max(1.0, np.abs(np.asarray(b)).max())
    assert not steps[True][0][:, k - dead:k].any()


@pytest.mark.parametrize("diagonal", [False, True])
def test_a_step_below_the_weights_resolution_is_not_computed(diagonal, monkeypatch):
    """Once ‖ΔW̃‖ ≤ ε‖W̃‖ (nothing float64 weights can resolve) the kept-rows step returns no direction and
    keeps M; the step a fresh rule computes at those weights (features, physics, residual: its own
    rounding) is at the rounding floor too — plus the features' correlations, at most UNCORRELATED,
    when their Gram was taken as diagonal — and the loss is at its floor."""
    from pdeinv.methods.hig import fixed as hig_fixed

    monkeypatch.setattr(hig_fixed, "UNCORRELATED", 1e-10 if diagonal else -1.0)
    p, model, Y = full_batch("wave")
    rule = HIG(route="kronecker")
    state = rule.init(p, model)
    params = list(model.parameters())
    losses = []
    for _ in range(400):
        u = rule.update(state, model, Y)
        losses.append(u.info["loss"])
        if all(d is None for d in u.direction):
            break
        with torch.no_grad():
            for q, d in zip(params, u.direction, strict=True):
                q.add_(d)
    else:
        pytest.fail("the step never fell below the weights' resolution")
    assert len(losses) > 3 and losses[-1] < 1e-20 * losses[0]
    assert rule.update(state, model, Y).info["loss"] == losses[-1]  # M kept
    exact = HIG(route="kronecker")
    fresh = exact.update(exact.init(p, model), model, Y)
    size = math.sqrt(sum(float(d.norm()) ** 2 for d in fresh.direction))
    weights = math.sqrt(sum(float(q.norm()) ** 2 for q in params))
    assert (state.context[-1].seen["carried"].fixed.A1.ndim == 1) == diagonal
    floor = 64 * torch.finfo(torch.float64).eps + (hig_fixed.UNCORRELATED if diagonal else 0.0)
    assert size <= floor * weights


def test_rows_keys_are_equal_for_the_same_rows_in_any_order_and_differ_by_one_ulp():
    from pdeinv.methods.hig import kron as hig_kron

    y = torch.randn(50, 13, dtype=torch.float64)
    goal = torch.randn(50, 13, dtype=torch.float64)
    perm = torch.randperm(50)
    assert hig_kron.rows_key(y) == hig_kron.rows_key(y[perm])
    assert hig_kron.rows_key(y, goal) == hig_kron.rows_key(y[perm], goal[perm])
    assert hig_kron.rows_key(y, goal) != hig_kron.rows_key(y, goal[perm])  # rows paired with other targets
    nudged = y.clone()
    nudged[7, 3] = torch.nextafter(nudged[7, 3], torch.tensor(math.inf, dtype=torch.float64))
    assert hig_kron.rows_key(nudged) != hig_kron.rows_key(y)
    assert hig_kron.rows_key(y[:, :12]) != hig_kron.rows_key(y)  # another width
    a, b = y[:1], y[1:2]  # a multiset: the same rows, not as often, are other rows
    assert hig_kron.rows_key(torch.cat([a, a, b])) != hig_kron.rows_key(torch.cat([a, b, b]))
    assert hig_kron.rows_key(torch.cat([a, b, a])) == hig_kron.rows_key(torch.cat([a, a, b]))


def test_the_rows_key_of_the_same_tensors_is_kept_until_they_change_in_place(monkeypatch):
    """A full-batch run passes the training tensors themselves: their key is hashed once; an in-place
    change (a new ``_version``) or other tensors are hashed again."""
    from pdeinv.methods.hig import kron as hig_kron

    calls = []
    real = hig_kron.rows_key
    monkeypatch.setattr(hig_kron, "rows_key", lambda *a: calls.append(1) or real(*a))
    gram = hig_kron.InputGram()
    y, goal = torch.randn(30, 5, dtype=torch.float64), torch.randn(30, 5, dtype=torch.float64)
    first = gram.key_of(y, goal)
    assert gram.key_of(y, goal) is first and len(calls) == 1
    assert gram.key_of(y.clone(), goal) == first and len(calls) == 2  # equal rows, other tensor
    y[3, 2] += 1.0
    assert gram.key_of(y, goal) != first and len(calls) == 3
    assert gram.key_of(y, None) != gram.key_of(y, goal)
