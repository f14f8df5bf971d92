"""The mesh-independent network (pdeinv.nets.reduced): size, gradients, default, save/load, accuracy."""

import json

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv import nets
from pdeinv.cli import main
from pdeinv.io.runs import load_run
from pdeinv.methods.presets import make_rule
from pdeinv.nets.whitening import Whitening
from pdeinv.training.trainer import Trainer

pytestmark = pytest.mark.usefixtures("one_thread")


def trained(model):
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


@pytest.mark.parametrize("body", ["linear", "mlp"])
def test_trained_parameter_count_does_not_depend_on_the_mesh(body):
    f = nets.reduced(k_in=24, k_out=20, body=body, hidden=(16,), k_max=20)
    small, big = (pdeinv.load_problem("heat_2d", n=n) for n in (8, 24))  # 49 and 529 unknowns
    a, b = f(small), f(big)
    assert trained(a) == trained(b) == (24 * 20 + 20 if body == "linear" else 24 * 16 + 16 + 16 * 20 + 20)
    assert sum(x.numel() for x in b.buffers()) > sum(x.numel() for x in a.buffers())  # buffers do grow
    full = nets.whitened("linear")(big)
    assert trained(full) == big.N * big.N + big.N  # what it replaces: N² + N


def test_the_head_starts_at_zero_and_the_decoder_is_orthonormal_and_fixed():
    p = pdeinv.load_problem("heat_2d", n=12)
    model = nets.reduced(k_in=16, k_out=16, k_max=16)(p)
    y = torch.randn(3, p.operator.n_out)
    with pytest.raises(RuntimeError, match="Whitening .* is not fitted"):  # never a silent pass-through
        model(y)
    nets.fit_preconditioning(model, p.sample(32, seed=1)[1])
    assert torch.count_nonzero(model(y)) == 0
    Phi = model.post.basis.double().T.numpy()  # (N, k) with ‖columns‖ ∝ the prior's rms amplitude
    G = Phi.T @ Phi
    assert np.abs(G - np.diag(np.diag(G))).max() < 1e-5 * np.diag(G).max()  # orthogonal columns
    assert np.all(np.diff(np.diag(G)) <= 1e-6)  # ordered by the prior's amplitude
    assert "post.basis" not in dict(model.named_parameters()) and "post.basis" in model.state_dict()


def test_the_decoder_captures_most_of_the_prior():
    p = pdeinv.load_problem("heat_2d", n=16)
    Phi, info = nets.prior_basis(p, 64)
    x, _ = p.sample(50, seed=3)
    Q = np.linalg.qr(Phi)[0]
    err = p.relative_error(x @ Q @ Q.T, x)
    assert info["components"] == 64 and info["captured"] > 0.99
    assert err.mean() < 0.1  # a 64-dimensional span holds the bumps to ~10 % (225 unknowns)


def test_gradcheck_through_the_reduced_network_in_float64():
    p = pdeinv.load_problem("heat_2d", n=8)
    model = nets.reduced(k_in=10, k_out=12, body="mlp", hidden=(6,))(p).double()
    y, _ = p.sample(40, seed=1)
    model.fit_observations(torch.as_tensor(y))
    for prm in model.parameters():  # away from the zero head, so every path carries gradient
        torch.nn.init.normal_(prm, std=0.3)
    yt = torch.as_tensor(y[:2]).requires_grad_(True)
    assert torch.autograd.gradcheck(model, (yt,), eps=1e-6, atol=1e-6)
    head = list(model.parameters())[-2]
    assert torch.autograd.gradcheck(lambda w: torch.func.functional_call(
        model, {n: (w if q is head else q) for n, q in model.named_parameters()}, (yt,)),
        (head.detach().clone().requires_grad_(True),), eps=1e-6, atol=1e-6)


def test_the_default_follows_reversibility_then_size(monkeypatch):
    """A non-reversible operator (heat) gets the prior decoder at any size; a reversible one (wave)
    keeps the whitened linear map up to REDUCED_ABOVE unknowns."""
    heat = pdeinv.load_problem("heat_2d", n=8)  # 49 unknowns
    model = nets.default_model(heat)
    assert isinstance(model.base.post, nets.Decoder) and isinstance(model.base.pre, Whitening)
    assert model.base.pre.k == min(nets.REDUCED_K_IN, heat.N) and model.decoder is not None
    assert nets.default_model(heat, rows_per_component=8).decoder is None  # first-order rules: no decoder
    wave = pdeinv.load_problem("wave_2d", n=8)
    assert nets.REDUCED_ABOVE >= 961  # wave_2d at its default size keeps the whitened linear map
    assert nets.default_model(wave).decoder is None
    monkeypatch.setattr(nets.defaults, "REDUCED_ABOVE", wave.N - 1)
    assert nets.default_model(wave).decoder is not None


def test_the_decoder_grows_once_where_its_columns_miss_the_prior():
    """decoder_basis: k columns that are all kept and still miss more than `uncaptured` are redrawn once,
    up to k_max columns; a prior that k columns hold is left at its own width."""
    p = pdeinv.load_problem("heat_2d", n=24)  # 529 unknowns: 20 columns miss far more than 1e-10
    small, info_small = nets.prior_basis(p, 20)
    grown, info = nets.decoder_basis(p, 20, 80)
    assert small.shape[1] == 20 and grown.shape[1] == info["components"] == 80
    assert info["samples"] == 160 and 1 - info["captured"] < 0.1 * (1 - info_small["captured"])
    fits, info_fits = nets.decoder_basis(p, 20, 80, uncaptured=1e-2)  # 20 hold all but 1 %: no growth
    assert fits.shape[1] <= 20 and info_fits["samples"] == 80
    x, _ = p.sample(40, seed=4)
    err = [p.relative_error(x @ Q @ Q.T, x).mean() for Q in (np.linalg.qr(B)[0] for B in (small, grown))]
    assert err[1] < 0.5 * err[0]
    assert nets.reduced(k_in=16, k_out=20, k_max=80)(p).decoder.shape[0] == 80
    # 35 columns hold all but 1e-3: more than k, but the first 80 draws resolve them (two per column)
    wider, info_wider = nets.decoder_basis(p, 20, 80, uncaptured=1e-3)
    assert 20 < wider.shape[1] <= 40 and info_wider["samples"] == 80
    assert 1 - info_wider["captured"] <= 1e-3


def test_the_decoder_keeps_what_the_prior_fills():
    """prior_basis stops at the components holding all but `uncaptured` of the drawn energy."""
    p = pdeinv.load_problem("heat_1d")
    full, _ = nets.prior_basis(p, 64, samples=256)
    cut, info = nets.prior_basis(p, 64, samples=256, uncaptured=1e-6)
    one_less = nets.prior_basis(p, cut.shape[1] - 1, samples=256)[1]
    assert cut.shape[1] < full.shape[1]
    assert 1 - info["captured"] <= 1e-6 < 1 - one_less["captured"]


def test_the_memory_estimate_follows_the_default_network(monkeypatch):
    wave = pdeinv.load_problem("wave_2d", n=8)
    full, _ = nets.default_size(wave)
    model = nets.default_model(wave)
    buffers = model.base.pre.basis.numel() + sum(b.numel() for b in model.correction.grid.buffers())
    assert full - nets.refined_size(wave) == sum(x.numel() for x in model.base.parameters()) + \
        model.base.pre.basis.numel()
    assert sum(x.numel() for x in model.parameters()) + buffers <= full
    heat = pdeinv.load_problem("heat_2d", n=8)
    est, _ = nets.default_size(heat)  # an upper bound: the decoder may keep fewer columns
    model = nets.default_model(heat)
    size = sum(x.numel() for x in model.parameters()) + model.base.post.basis.numel()
    assert size <= est


def test_bad_sizes_and_bodies_are_refused():
    with pytest.raises(ValueError, match="k_in=0 is not allowed"):
        nets.reduced(k_in=0)
    with pytest.raises(ValueError, match="k_out=2.5 is not allowed"):
        nets.reduced(k_out=2.5)
    with pytest.raises(ValueError, match="body='cnn' is not allowed"):
        nets.reduced(body="cnn")
    with pytest.raises(ValueError, match="components=0 is not allowed"):
        Whitening(10, components=0)


def test_a_run_with_the_reduced_default_resumes_and_predicts(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(nets.defaults, "REDUCED_ABOVE", 100)  # heat_2d n=16 (225 unknowns): reduced
    out = tmp_path / "run"
    # 4 SIP steps of batch 8 end at x_err 11.8 (pdeinv.training.verdict: exit 3), kept: resuming is the
    # point here
    args = ["train", "--prior-fit", "0",
            "heat_2d", "--set", "n=16", "--n-train", "64", "--n-test", "16", "--batch-size", "8",
            "--threads", "1", "--export-samples", "0", "--checkpoint-every", "2", "--accept-bad",
            "--out", str(out)]
    assert main([*args, "--steps", "4"]) == 0
    assert json.loads((out / "run.json").read_text())["network"] == {"kind": "default", "correction": "grid"}
    problem, model = load_run(out)
    assert isinstance(model.base.post, nets.Decoder) and bool(model.base.pre.fitted)
    x, y = problem.sample(4, seed=9)
    with torch.no_grad():
        pred = model(torch.as_tensor(y, dtype=torch.float32)).numpy()
    assert pred.shape == x.shape and np.isfinite(pred).all() and np.abs(pred).max() > 0
    assert main([*args, "--steps", "6", "--resume"]) == 0
    assert json.loads((out / "metrics.json").read_text())["steps"] == 6
    capsys.readouterr()


def test_short_sip_training_on_heat_2d_reaches_the_measured_error():
    """heat_2d n=16 (225 unknowns), SIP with the CLI's defaults, 300 steps: measured x-error
    0.141 for the reduced linear network (0.079 for the whitened linear map); threshold 0.2."""
    p = pdeinv.load_problem("heat_2d", n=16)
    rule, hp = make_rule("sip", p.name, p.noise)
    torch.manual_seed(0)
    model = nets.reduced()(p)
    result = Trainer(p, rule, model, steps=300, eval_every=300, batch_size=hp["batch_size"],
                     progress=False, prior=None).fit()
    assert result.metrics["x_err"] < 0.2


def test_the_reduced_network_is_selectable_by_name_in_a_run_record():
    from pdeinv.io.runs import network

    p = pdeinv.load_problem("heat_2d", n=8)
    model = network(p, {"kind": "reduced", "k_in": 12, "k_out": 10, "k_max": 10})
    assert isinstance(model.post, nets.Decoder) and model.pre.k == 12 and model.post.basis.shape == (10, p.N)


@pytest.mark.parametrize("n", [8, 200])
def test_whitening_with_k_components_keeps_the_leading_directions(n):
    """components=k: basis (m, k) with orthonormal columns, the k leading PCA directions first;
    with fewer samples than k the unvisited directions are zero columns and dropped (gain 0)."""
    rng = np.random.default_rng(0)
    m, k = 40, 12
    scales = np.logspace(0, -3, m)
    y = rng.standard_normal((n, m)) * scales
    w = Whitening(m, components=k).double().fit(y)
    U, g = w.basis.numpy(), w.gain.numpy()
    visited = min(k, n)  # the thin SVD's directions; the rest are zero columns (gain 0, never seen)
    assert U.shape == (m, k) and np.allclose(U[:, :visited].T @ U[:, :visited], np.eye(visited), atol=1e-10)
    assert np.all(U[:, visited:] == 0)
    full = Whitening(m).double().fit(y)
    lead = min(k, n - 1)
    assert np.allclose(np.abs(U[:, :lead].T @ full.basis.numpy()[:, :lead]), np.eye(lead), atol=1e-8)
    assert np.allclose(g[:lead], full.gain.numpy()[:lead])
    assert np.all(g[lead:] == 0)  # directions no sample visited
    assert w(torch.as_tensor(y)).shape == (n, k)


def test_one_normalized_sip_step_is_newtons_step_on_the_scaled_decoder():
    """x = Φ(W z̃): the proxy's Gauss–Newton matrix is (Z̃ᵀZ̃/B) ⊗ ΦᵀΦ, diagonal for whitened z on the
    full batch and Φ with orthogonal columns scaled by the prior (condition number ~1e8 here). SIP's
    Jacobi-normalized step at lr 1 lands on the proxy's least-squares solution in one step; by λ_max
    alone it would move the weakest column by ~1e-8 of that."""
    p = pdeinv.load_problem("heat_1d", n=32, steps=10)
    model = nets.reduced(k_in=8, k_out=12, k_max=12)(p)  # 8 whitened directions: z exact to ~1e-12
    _, y = p.sample(200, seed=0)
    nets.fit_preconditioning(model, y)
    Y = torch.as_tensor(y, dtype=torch.float64)
    phi = model.post.basis.T.numpy()  # (N, k_out)
    s2 = (phi**2).sum(0)
    assert s2.max() / s2.min() > 1e3  # the decoder really is badly scaled
    rule = pdeinv.SIP()
    state = rule.init(p, model)
    with torch.no_grad():
        z = model.pre(Y).numpy()
    # x = 0 before the step: x̃ = the rule's local inverse of y* (for a decoder: the solve in its span)
    x_tilde = state.context.inverse(y, np.zeros_like(y[:, : p.operator.n_in]))
    rule.step(state, model, Y)
    zt = np.hstack([z, np.ones((len(z), 1))])
    coef = np.linalg.lstsq(zt, np.linalg.lstsq(phi, x_tilde.T, rcond=None)[0].T, rcond=None)[0]
    best = zt @ coef @ phi.T  # argmin over (W, b) of Σ_i ‖Φ(W z_i + b) − x̃_i‖²
    x = model(Y).detach().numpy()
    assert np.abs(x - best).max() < 1e-9 * np.abs(best).max()


def test_sip_on_a_decoder_inverts_inside_its_span():
    """The default SIP inverse for x = D c is local with its change the Tikhonov solve in span D: from
    any x₀ the change lies in the span, and on fields of the span it inverts the physics exactly; a
    user's inverse still wins."""
    from pdeinv.inverse.decoder import DecoderTikhonov
    from pdeinv.methods.sip import decoder_inverse

    p = pdeinv.load_problem("heat_1d", n=32, steps=10)
    model = nets.reduced(k_in=8, k_out=6, k_max=6)(p)
    inverse = pdeinv.SIP().context(p, model).inverse
    assert isinstance(inverse, DecoderTikhonov) and decoder_inverse(p, nets.whitened()(p)) is None
    D = model.post.basis.numpy()  # (k, N): rows are the decoder's columns
    c = np.random.default_rng(0).standard_normal((5, D.shape[0]))
    x = c @ D
    xt = inverse(p.operator.forward(x), np.zeros_like(x))
    assert np.abs(xt - x).max() < 1e-6 * np.abs(x).max()  # exact on the span (weakest s ~ 1e-3·s_max)
    x0, y = p.sample(5, 1)
    change = inverse(y, x0[::-1]) - x0[::-1]  # from any x₀, not in the span
    coef = np.linalg.lstsq(D.T, change.T, rcond=None)[0]
    assert np.abs(coef.T @ D - change).max() < 1e-10 * np.abs(change).max()
    assert pdeinv.SIP(inverse=p.inverse).context(p, model).inverse == p.inverse


@pytest.mark.parametrize("factory", [nets.whitened("linear"), nets.reduced(k_in=20, k_out=12)])
def test_the_exact_curvature_equals_power_iteration(factory):
    """Net.gauss_newton_max (two small eigenproblems) against the power iteration through the network,
    with the Jacobi normalization SIP uses, on a problem small enough to iterate to convergence."""
    from pdeinv.methods.curvature import gauss_newton_max

    p = pdeinv.load_problem("heat_2d", n=8)
    model = factory(p)
    _, y = p.sample(64, seed=1)
    Y = torch.as_tensor(y, dtype=torch.float64)
    nets.fit_preconditioning(model, Y)
    diag = tuple(torch.where(d > 0, d, torch.ones_like(d)) for d in model.gauss_newton_diagonal(Y))
    slow = gauss_newton_max(model, Y, iters=500, diagonal=diag)
    assert model.gauss_newton_max(Y) == pytest.approx(slow, rel=1e-6)
    assert nets.whitened("mlp", hidden=(4,))(p).gauss_newton_max(Y) is None


def test_noisy_observations_take_a_shorter_decoder():
    """The default decoder may leave out (NOISY_FLOOR·σ)² of the prior's energy at relative noise σ: fewer
    columns (each one forward solve before training), an error floor of a twentieth of the noise."""
    from pdeinv.nets.defaults import linear_default
    from pdeinv.nets.reduced import NOISY_FLOOR, REDUCED_UNCAPTURED, decoder_uncaptured

    assert decoder_uncaptured(None) == decoder_uncaptured(0.0) == REDUCED_UNCAPTURED
    assert decoder_uncaptured(0.01) == pytest.approx((NOISY_FLOOR * 0.01) ** 2)
    k = {}
    for noise in (0.0, 0.01):
        net = linear_default(pdeinv.load_problem("heat_2d", n=24, noise=noise))
        k[noise] = net.decoder.shape[0]
        assert 1 - net.decoder_info["captured"] <= decoder_uncaptured(noise)
    assert k[0.01] < 0.8 * k[0.0], k


@pytest.mark.parametrize("scene, n", [("heat_boxes", 16), ("heat_2d", 16)])
def test_a_decoder_refused_by_its_spectrum_is_the_one_it_would_have_built(scene, n):
    """``at_most`` decides from the spectrum alone: ``None`` exactly where the decoder, built, leaves more
    than that fraction of the prior's energy out, with the same captured fraction and columns."""
    from pdeinv.nets.reduced import decoder_basis

    p = pdeinv.load_problem(scene, n=n)
    Phi, built = decoder_basis(p, k=16, k_max=64)  # grows: 16 < 64 < 225 unknowns
    at_most = 1e-6
    basis, decided = decoder_basis(p, k=16, k_max=64, at_most=at_most)
    assert decided["samples"] == built["samples"]
    assert decided["captured"] == pytest.approx(built["captured"], abs=1e-10)
    assert (basis is None) == (1 - built["captured"] > at_most)
    if basis is not None:
        np.testing.assert_array_equal(basis, Phi)
