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
    # dense (gram route) ≈ 236 kB; the 10-probe sketch ≈ 102 kB (its arrays ≈ 70 kB and the activations
    # of the physics' time steps); the MLP's last-layer step (pdeinv.methods.hig.layers) ≈ 2 kB: a dense
    # network takes that instead
    _, info = _delta(p, model, y, route="auto", probes=10, max_jacobian_gb=120e3 / 2**30)
    assert info["route"] == "last_layer"
    _, info = _delta(p, model, y, wrap=True, route="auto", probes=10, max_jacobian_gb=120e3 / 2**30)
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


@pytest.fixture(scope="module")
def conv_batch():
    """A small U-Net on heat_boxes as HIG's routes see it: activations, not parameters, dominate."""
    from pdeinv import load_problem
    from pdeinv.methods.hig.routes import Batch
    from pdeinv.methods.hig.rule import compress
    from pdeinv.nets import unet

    p = load_problem("heat_boxes", n=12)
    torch.manual_seed(0)
    net = unet(channels=4, refine=False)(p).double()
    torch.nn.init.normal_(net.unet.out.weight, std=0.1)
    y = torch.as_tensor(p.sample(4, seed=1)[1])
    net.fit_observations(y)
    return Batch.of(net, compress(p.operator)[0], y)


def test_probes_in_chunks_give_the_same_step(conv_batch):
    """The probes go through vmap in chunks bounded by their activations: one probe at a time gives the
    step all at once gives, to rounding."""
    from pdeinv.methods.hig.randomized import randomized_direction

    g = torch.randn(conv_batch.rows, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    whole, a = randomized_direction(conv_batch, g, 12, 1, 1e-6, -0.5, 1.0, seed=3, activations=0)
    alone, b = randomized_direction(conv_batch, g, 12, 1, 1e-6, -0.5, 1.0, seed=3, activations=10**15)
    assert (a["chunk"], b["chunk"]) == (12, 1)
    assert float((whole - alone).norm() / whole.norm()) < 1e-10


def test_the_matrix_free_memory_counts_the_activations_of_a_chunk(conv_batch):
    """The route's memory is its arrays, the vjp's saved activations and one chunk of probes' copies:
    what a batch saves grows with the batch, and a chunk stays within ACTIVATION_BYTES."""
    from pdeinv.methods.hig import randomized as R
    from pdeinv.methods.hig.routes import MatrixFree

    act = R.activation_bytes(conv_batch)
    half = R.activation_bytes(conv_batch._replace(y=conv_batch.y[:2], rows=conv_batch.rows // 2))
    assert 1.8 < act / half < 2.2  # activations per sample, not per parameter
    route, probes = MatrixFree(probes=16, power_iters=1, seed=0), 16
    arrays = R.memory_bytes(conv_batch.n_params, probes, conv_batch.rows)
    assert route.memory(conv_batch) == arrays + act + probes * R.COPIES * act
    most = R.chunk(10**6, act)
    assert most * R.COPIES * act <= R.ACTIVATION_BYTES < (most + 1) * R.COPIES * act
