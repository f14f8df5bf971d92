"""The nonlinear default: grid maps, the priors, the refined network and its prior fit."""

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.fem.grid import GridMap, spacing
from pdeinv.methods.presets import make_rule
from pdeinv.nets.refine import PriorFit, Refined
from pdeinv.problem.sampling import boxes, gaussian_random_field
from pdeinv.training.plan import PriorStage


@pytest.mark.parametrize("name, kw", [("heat_1d", {}), ("heat_boxes", {"n": 8}), ("heat_3d", {"n": 4})])
def test_grid_round_trip_is_the_identity_on_structured_meshes(name, kw):
    p = pdeinv.load_problem(name, **kw)
    g = GridMap(p.points, spacing(p.disc.basis.mesh))
    x = torch.as_tensor(np.random.default_rng(0).standard_normal((3, p.N)))
    assert torch.allclose(g.to_mesh(g.to_grid(x)), x, atol=1e-12)


def test_grid_to_mesh_is_exact_for_multilinear_fields_on_an_unstructured_mesh():
    p = pdeinv.load_problem("heat_plate")  # gmsh triangles: nodes are not grid points
    g = GridMap(p.points, spacing(p.disc.basis.mesh))
    axes = [torch.linspace(float(lo), float(hi), s, dtype=torch.float64)
            for lo, hi, s in zip(p.points.min(1), p.points.max(1), g.shape, strict=True)]
    X, Y = torch.meshgrid(*axes, indexing="ij")
    f = lambda x, y: 0.3 + 2 * x - y + 0.5 * x * y  # noqa: E731  bilinear: the interpolation is exact
    out = g.to_mesh(f(X, Y)[None, None])[0].numpy()
    assert np.allclose(out, f(*p.points), atol=1e-12)


def test_box_prior_is_piecewise_constant_with_the_papers_statistics():
    pts = np.stack(np.meshgrid(np.linspace(0, 1, 65), np.linspace(0, 1, 65))).reshape(2, -1)
    x = boxes(pts, 200, np.random.default_rng(0))
    assert x.min() >= 0 and x.max() <= 10
    assert np.mean([len(np.unique(r)) for r in x]) < 60  # a few plateaus, not a smooth field
    assert (x[:, (pts[0] < 0.02) | (pts[0] > 0.98)] == 0).mean() > 0.9  # centres in the central 80 %


def test_gaussian_random_field_has_the_squared_exponential_covariance():
    pts = np.array([[0.0, 0.05, 0.1, 0.3]])  # 1-D, bounding box diameter 0.3: ℓ = 0.03
    x = gaussian_random_field(pts, 20000, np.random.default_rng(1))
    cov = x.T @ x / len(x)
    d = pts[0][:, None] - pts[0][None, :]
    assert np.allclose(cov, np.exp(-d**2 / (2 * 0.03**2)), atol=0.05)


def test_refined_network_is_its_base_until_the_correction_is_fitted():
    p = pdeinv.load_problem("heat_1d")
    net = p.model()
    assert isinstance(net, Refined)
    y = torch.as_tensor(p.sample(8, 0)[1])
    net.fit_observations(y.numpy())
    assert torch.equal(net(y), net.base(y))
    assert net.linear_in_parameters() is not None  # the base's structure is declared through
    assert not any(q.requires_grad for q in net.correction.parameters())


def _oracles(p, xt, yt):
    """(linear MMSE fitted on 16 384 prior draws, best-α Tikhonov): each the best over its α."""
    err = lambda a: float(np.mean(p.relative_error(a, xt)))  # noqa: E731
    xs, ys = p.sample(16384, seed=99)
    mx, my = xs.mean(0), ys.mean(0)
    Cyy, Cxy = (ys - my).T @ (ys - my) / len(ys), (xs - mx).T @ (ys - my) / len(ys)
    lam = np.linalg.eigvalsh(Cyy).max()
    mmse = min(err(mx + (yt - my) @ np.linalg.solve(Cyy + r * lam * np.eye(len(Cyy)), Cxy.T))
               for r in 10.0 ** np.arange(-20, -1))
    U, s, Vt = np.linalg.svd(p.operator.forward(np.eye(p.N)).T)
    tikhonov = min(err(((yt @ U) * (s / (s**2 + r * s[0] ** 2))) @ Vt) for r in 10.0 ** np.arange(-30, 0))
    return mmse, tikhonov


@pytest.mark.slow
def test_nonlinear_default_beats_every_linear_estimator_on_a_small_box_scene():
    """heat_boxes n=16 (225 unknowns, κT = 8 cells²), SIP's preset, the prior fit on 2048 draws for
    700 steps: measured 0.220 (1500 steps: 0.210) against the MMSE's 0.406 and best-α Tikhonov's 0.338
    (the rule's linear network alone: 0.367)."""
    p = pdeinv.load_problem("heat_boxes", n=16)
    rule, hp = make_rule("sip", p, p.noise)
    res = pdeinv.train(p, rule, steps=hp["steps"], batch_size=hp["batch_size"], seed=0, progress=False,
                       prior=PriorStage(PriorFit(steps=700), draws=2048))
    info = res.metrics["stages"][1]
    assert info["kept"] and "boxes" in info["prior"]
    xt, yt = pdeinv.Trainer(p, rule, res.model, steps=1).held_out()
    mmse, tikhonov = _oracles(p, xt, yt)
    assert res.metrics["x_err"] < 0.75 * min(mmse, tikhonov), (res.metrics["x_err"], mmse, tikhonov)
    assert info["error_after"] < 0.75 * info["error_before"]


def test_prior_comes_from_the_data_file_and_never_from_the_scene_sampler():
    p = pdeinv.load_problem("heat_1d")
    x, y = p.sample(300, seed=3)
    rule, hp = make_rule("sip", p, p.noise)
    stage = PriorStage(PriorFit(steps=20))
    with_x = pdeinv.train(p, rule, data=y, data_x=x, n_test=50, steps=2, batch_size=None, progress=False,
                          prior=stage)
    assert with_x.metrics["stages"][1]["prior"] == "the data file's x (250 training rows)"
    assert with_x.metrics["stages"][1]["draws"] == 250
    only_y = pdeinv.train(p, rule, data=y, n_test=50, steps=2, batch_size=None, progress=False, prior=stage)
    assert only_y.metrics["stages"][1] == {"name": "prior", "kept": False,
                                           "skipped": "no prior: the data file has no x",
                                           "seconds": only_y.metrics["stages"][1]["seconds"]}
    assert not bool(only_y.model.active)


def test_cli_runs_the_prior_stage_by_default_and_records_it(tmp_path):
    """Without --prior-fit the stage's counts are the problem's (stages.draw_count, PriorFit's passes);
    --prior-fit N caps its steps; a negative count is refused."""
    import json

    from pdeinv.cli import main
    from pdeinv.training.plan import draw_count

    p = pdeinv.load_problem("heat_1d", n=16)
    assert main(["train", "heat_1d", "--set", "n=16", "--set", "noise=0.02", "--steps", "3", "--prior-fit",
                 "30", "--out", str(tmp_path / "r"), "--threads", "1"]) == 0  # noisy: SIP not within 1 %
    stages = json.loads((tmp_path / "r" / "metrics.json").read_text())["stages"]
    assert [s["name"] for s in stages] == ["sip", "prior", "calibration"]
    assert stages[1]["prior"] == f"{draw_count(p.N)} draws of the scene's prior (bumps)"
    assert stages[1]["draws"] == draw_count(p.N) and stages[1]["steps"] <= 30
    assert main(["train", "heat_1d", "--steps", "3", "--prior-fit", "-1", "--out", str(tmp_path / "s")]) == 2


def test_own_data_takes_no_prior_from_the_scene(tmp_path):
    """A data file's run: the linear part is the whitened map (fitted on the file's y; no decoder from the
    scene's sampler), recorded in run.json, and predict rebuilds it."""
    import json

    from pdeinv.cli import main

    p = pdeinv.load_problem("heat_1d", prior="boxes")
    x, y = p.sample(200, seed=4)
    np.savez(tmp_path / "d.npz", x=x, y=y)
    out = tmp_path / "run"
    assert main(["train", "heat_1d", "--data", str(tmp_path / "d.npz"), "--n-test", "40", "--steps", "3",
                 "--prior-fit", "2", "--out", str(out), "--threads", "1"]) == 0
    spec = json.loads((out / "run.json").read_text())["network"]
    assert spec["base"] == "whitened"
    fit = json.loads((out / "metrics.json").read_text())["stages"][1]
    assert fit["prior"].startswith("the data file's x")
    d, pred = str(tmp_path / "d.npz"), str(tmp_path / "p.npz")
    assert main(["predict", str(out), "--data", d, "--out", pred]) == 0
    model = pdeinv.load_problem("heat_1d").model(base="whitened")
    assert model.base.decoder is None


def test_a_decoder_that_misses_the_prior_gives_way_to_the_modal_or_the_whitened_map(monkeypatch):
    """The box prior is not captured by the decoder (its error floor would be the missing energy's square
    root; heat_boxes 64×64 SIP: 1.07 with it); smooth bumps are. In its place a rule that converges (SIP,
    HIG) gets the linear map in the operator's modes (k² numbers: model.pt 10 MB at 64², not 131), a
    first-order rule (a whitening cap) the whitened map."""
    from pdeinv import nets
    from pdeinv.nets.modal import ModalFeatures

    monkeypatch.setattr(nets.defaults, "REDUCED_ABOVE", 100)  # heat_2d's bumps get the decoder at any size
    boxes = pdeinv.load_problem("heat_boxes", n=32)  # 512 of 961: not all
    boxes_net, capped = nets.linear_default(boxes), nets.linear_default(boxes, rows_per_component=8)
    bumps_net = nets.linear_default(pdeinv.load_problem("heat_2d", n=32))
    assert isinstance(boxes_net.pre, ModalFeatures)  # the modal map, its decoder the operator's modes
    assert capped.decoder is None and not isinstance(capped.pre, ModalFeatures)  # the whitened map
    assert bumps_net.decoder is not None and not isinstance(bumps_net.pre, ModalFeatures)
    assert 1 - bumps_net.decoder_info["captured"] <= nets.DECODER_MAX_UNCAPTURED
    count = lambda net: sum(q.numel() for q in net.parameters())  # noqa: E731
    assert nets.network_size(boxes, "linear")["params"] >= count(boxes_net)  # the size model's upper bound
    assert nets.network_size(boxes, "linear", rows_per_component=8)["params"] >= count(capped)


def test_the_physics_channel_is_the_tikhonov_solve_from_zero():
    """SpectralFilter(y) = SpectralTikhonov(y, x0=0) at the same relative α: the physics' own full-rank
    estimate that the correction sees beside the learned base (heat scenes on the modal backend)."""
    from pdeinv.inverse import RelativeAlpha, SpectralTikhonov
    from pdeinv.nets.refine import SpectralFilter

    p = pdeinv.load_problem("heat_boxes", n=16, noise=0.01)
    _, y = p.sample(4, 0)
    net = p.model()
    assert isinstance(net.correction.physics, SpectralFilter)
    assert net.correction.unet.down[0][0].in_channels == 2
    ref = SpectralTikhonov(p.operator, RelativeAlpha(0.01**2))(y, np.zeros((4, p.N)))
    assert np.allclose(net.correction.physics(torch.as_tensor(y)).numpy(), ref, rtol=1e-10, atol=1e-12)
    assert not any(k.endswith("physics.proj") for k in net.state_dict())  # rebuilt, not saved


def test_a_small_1d_mesh_gets_the_dense_correction_and_others_the_grid():
    """The correction's kind follows the mesh and the physics: a dense MLP on (y, b(y)) up to
    DENSE_MAX_UNKNOWNS unknowns on 1-D meshes (a 1-D U-Net sees ~20 neighbours; waves and reactions move
    information further) and on any mesh with nonlinear physics, the U-Net on a grid otherwise."""
    from pdeinv.nets import DENSE_MAX_UNKNOWNS, correction_kind, refined_size
    from pdeinv.nets.refine import DenseCorrection, GridCorrection

    sg, flat = pdeinv.load_problem("sine_gordon_1d"), pdeinv.load_problem("heat_2d", n=8)
    big = pdeinv.load_problem("heat_1d", n=DENSE_MAX_UNKNOWNS + 2)
    sg2, ac2 = pdeinv.load_problem("sine_gordon_2d", n=8), pdeinv.load_problem("allen_cahn_2d", n=8)
    kinds = [correction_kind(p) for p in (sg, big, flat, sg2, ac2)]
    assert kinds == ["dense", "grid", "grid", "dense", "dense"]
    net = sg.model()
    assert isinstance(net.correction, DenseCorrection) and net.correction_kind == "dense"
    assert isinstance(flat.model().correction, GridCorrection)
    assert sum(q.numel() for q in net.correction.parameters()) <= refined_size(sg)
    y = torch.as_tensor(sg.sample(4, 0)[1])
    net.fit_observations(y.numpy())
    assert torch.equal(net(y), net.base(y))  # the zero last layer: f = b until the fit keeps g


def test_a_dense_correction_is_fitted_saved_and_reloaded(tmp_path):
    """fit_prior with the dense correction lowers the held-out error of a poor base on sine_gordon_1d
    prior draws (a nonlinear map: the whitened linear part alone is at its affine floor), and a saved run
    reloads to the same predictions (run.json records the kind)."""
    import json

    from pdeinv.io.runs import load_run, save_run

    p = pdeinv.load_problem("sine_gordon_1d")
    net = p.model()
    x, y = p.sample(2048, 1)
    net.fit_observations(y)
    info = net.fit_prior(x, y, p.relative_error, PriorFit(steps=600))
    assert info["kept"] and info["error_after"] < 0.9 * info["error_before"]
    out = save_run(tmp_path / "r", p, model=net)
    assert json.loads((out / "run.json").read_text())["network"] == {"kind": "default", "correction": "dense"}
    _, again = load_run(out)
    yt = torch.as_tensor(p.sample(8, 2)[1])
    with torch.no_grad():
        assert torch.allclose(again(yt), net(yt), rtol=0, atol=1e-6)


def test_the_correction_starts_from_the_least_squares_blend_of_base_and_physics_filter():
    """b_λ = b + λ (x_T − b) with λ the least-squares blend on the training draws: an untrained base (zero)
    is far off, the physics filter x_T is not; the fit's first check (g = 0) keeps b_λ, no worse than either,
    λ minimizes the squared error along the blend, and the network returns exactly b_λ."""
    p = pdeinv.load_problem("heat_boxes", n=16)
    net = p.model()
    x, y = p.sample(1024, 1)
    net.fit_observations(y)
    info = net.fit_prior(x, y, p.relative_error, PriorFit(steps=0))
    yt = torch.as_tensor(y)
    with torch.no_grad():
        b, t = net.base(yt).numpy(), net.correction.physics(yt).numpy()
        out = net.corrected(yt, net.base(yt)).numpy()  # before the data-consistency layer
    d = t - b
    lam = float(np.sum((x - b) * d) / np.sum(d * d))  # over all draws: the fit used 7/8 of them
    err = lambda a: float(np.mean(p.relative_error(a, x)))  # noqa: E731
    assert info["kept"] and info["steps"] == 0 and info["mix"] == pytest.approx(lam, rel=0.05)
    np.testing.assert_allclose(out, b + info["mix"] * d, rtol=1e-5, atol=1e-6 * np.abs(out).max())
    assert err(out) <= min(err(b), err(t)) * (1 + 1e-6), (err(out), err(b), err(t))
    sq = lambda m: float(np.sum((b + m * d - x) ** 2))  # noqa: E731  the least-squares objective
    assert sq(info["mix"]) < min(sq(0.9 * info["mix"]), sq(1.1 * info["mix"]), sq(0.0), sq(1.0))
    assert info["error_corrected"] < info["error_before"]


@pytest.mark.parametrize("name, kw, atol", [("sine_gordon_1d", {}, 1e-6), ("heat_boxes", {"n": 16}, 1e-3)])
def test_a_feed_computed_per_batch_fits_the_same_correction(monkeypatch, name, kw, atol):
    """Above STORED_ENTRIES the base's estimates and the correction's inputs are computed per batch instead
    of stored for all draws (heat_2d at 65 025 unknowns: 1.2 GB less): the same steps, the same fit (with
    the physics filter and its blend on heat_boxes)."""
    from pdeinv.nets import refine

    p = pdeinv.load_problem(name, **kw)
    x, y = p.sample(512, 1)
    fits = []
    for entries in (refine.STORED_ENTRIES, 0):
        monkeypatch.setattr(refine, "STORED_ENTRIES", entries)
        monkeypatch.setattr(refine, "PREPARE_ROWS", 10**9)
        torch.manual_seed(0)
        net = p.model()
        net.fit_observations(y)
        info = net.fit_prior(x, y, p.relative_error, PriorFit(steps=60))
        with torch.no_grad():
            fits.append((info, net(torch.as_tensor(y[:8])).numpy()))
    (a, out_a), (b, out_b) = fits
    assert a["steps"] == b["steps"] == 60 and a["kept"] == b["kept"]
    assert a["error_after"] == pytest.approx(b["error_after"], rel=1e-4)
    assert a["mix"] == b["mix"]
    # the U-Net sums float32 convolutions in another order per batch size: 2.8e-4 of the largest (60 steps)
    np.testing.assert_allclose(out_a, out_b, rtol=1e-4, atol=atol * np.abs(out_a).max())


def test_prior_draws_are_priced_by_the_operators_forward_cost():
    """A costly forward caps the stage's draws at DRAW_FLOPS' worth (never below 256); the linear scenes'
    compiled draws are too cheap to be capped; the cost models grow with the time steps."""
    from pdeinv.training.plan import DRAW_FLOPS, FEWEST_DRAWS, PriorStage, draw_count

    assert draw_count(225, None) == draw_count(225) == 65536
    assert draw_count(225, DRAW_FLOPS / 1000) == 1000 and draw_count(225, DRAW_FLOPS) == FEWEST_DRAWS
    ac = pdeinv.load_problem("allen_cahn_2d")
    flops = ac.operator.forward_flops()
    assert PriorStage().draw_count(ac) == int(DRAW_FLOPS // flops) < 20_000
    ac2 = pdeinv.load_problem("allen_cahn_2d", steps=100)
    assert ac2.operator.forward_flops() == pytest.approx(2 * flops)
    sg = pdeinv.load_problem("sine_gordon_1d")
    sg2 = pdeinv.load_problem("sine_gordon_1d", T=2.0)
    assert sg2.operator.forward_flops() > 1.9 * sg.operator.forward_flops() > 0
    for name in ("heat_1d", "heat_boxes", "wave_2d"):  # compiled: BLAS products of the stored map
        p = pdeinv.load_problem(name)
        assert p.operator.backend is not None
        assert 0 < p.operator.forward_flops() < p.operator.step_flops()
        assert PriorStage().draw_count(p) == draw_count(p.N)
    assert pdeinv.load_problem("heat_1d").operator.stepping().forward_flops() == pytest.approx(
        pdeinv.load_problem("heat_1d").operator.step_flops())


def test_prior_draws_are_a_count_of_the_unknowns_and_the_same_for_the_same_seed(monkeypatch):
    from pdeinv.training.plan import draw_count
    from pdeinv.training.trainset import prior_rows

    assert draw_count(63) == 65536 and draw_count(3969) == 5039 and draw_count(29929) == 1670
    assert draw_count(10**6) == 256
    p = pdeinv.load_problem("heat_1d", n=16)
    monkeypatch.setattr("pdeinv.training.trainset.PRIOR_CHUNK", 64)
    (x0, _), source = prior_rows(p, None, 64 + 8, 0)
    (x1, _), _ = prior_rows(p, None, 64 + 8, 0)
    assert x0.shape == (64 + 8, p.N) and source.startswith("72 draws")
    assert np.array_equal(x0, x1)
    (x2, _), _ = prior_rows(p, None, 8, 0, stream=1)  # the stage's pilot draws: their own stream
    assert not np.array_equal(x2, x0[:8])


def test_the_unet_fit_batch_shrinks_with_the_unfolded_grid():
    """32 draws per prior-fit step on small grids; fewer where grid points × 3^dim × draws would pass
    FIT_BATCH_POINTS (the CPU convolutions' unfolded buffers: heat_3d at 29 791 unknowns held 4–5 GB per
    step with 32)."""
    from types import SimpleNamespace

    from pdeinv.nets.corrections import FIT_BATCH_POINTS, GridCorrection

    def batch(shape):
        return GridCorrection(SimpleNamespace(shape=shape)).fit_batch

    assert batch((63, 63)) == batch((15, 15, 15)) == 32
    assert batch((255, 255)) == FIT_BATCH_POINTS // (255 * 255 * 9) == 14
    assert batch((31, 31, 31)) == 10 and batch((99, 99, 99)) == 2


@pytest.mark.slow
def test_large_nonlinear_meshes_get_the_span_correction_which_fits_saves_and_reloads(tmp_path):
    """Above DENSE_MAX_UNKNOWNS on nonlinear physics the correction is the MLP in the base decoder's
    orthonormalized coordinates (SpanCorrection): its output lies in span D, it is zero until fitted, it
    lowers the held-out error of a linear base fitted by least squares on draws, and a saved run reloads."""
    from pdeinv.io.runs import load_run, save_run
    from pdeinv.nets import correction_kind
    from pdeinv.nets.refine import SpanCorrection

    torch.manual_seed(0)  # the network's initial weights: not whatever the tests before left in torch's RNG
    p = pdeinv.load_problem("sine_gordon_2d", n=72, T=0.1)
    assert p.N > pdeinv.nets.DENSE_MAX_UNKNOWNS and correction_kind(p) == "span"
    net = p.model()
    g = net.correction
    assert isinstance(g, SpanCorrection) and net.correction_kind == "span"
    Q = g.Q.double()
    assert torch.allclose(Q @ Q.T, torch.eye(Q.shape[0], dtype=torch.float64), atol=1e-4)
    x, y = p.sample(1536, 1)
    net.fit_observations(y)
    yt = torch.as_tensor(y)
    with torch.no_grad():  # the base's body by least squares on the draws' decoder coefficients
        D = net.base.decoder.double()
        c = torch.linalg.solve(D @ D.T, D @ torch.as_tensor(x).T).T
        z = net.base.pre(yt).double()
        A = torch.cat([z, torch.ones(len(z), 1, dtype=z.dtype)], 1)  # rank 193 of 1025: gelsy's pivoting
        W = torch.linalg.lstsq(A, c, rcond=1e-10, driver="gelsd").solution  # varies by machine, SVD not
        body = net.base.body[0] if isinstance(net.base.body, torch.nn.Sequential) else net.base.body
        body.weight.copy_(W[:-1].T)
        body.bias.copy_(W[-1])
        assert torch.equal(net(yt[:4]), net.base(yt[:4]))
    info = net.fit_prior(x, y, p.relative_error, PriorFit(steps=400))
    assert info["kept"] and info["error_after"] < 0.95 * info["error_before"], info  # 0.14 -> 0.09
    with torch.no_grad():
        out = net(yt[:8])
        coords = torch.linalg.solve(D @ D.T, D @ out.T).T @ D  # the field is in span D
    assert torch.allclose(coords, out, atol=1e-5 * float(out.abs().max()))
    run = save_run(tmp_path / "r", p, overrides={"n": 72, "T": 0.1}, model=net)
    _, again = load_run(run)
    with torch.no_grad():
        assert torch.allclose(again(yt[:8]), out, rtol=0, atol=1e-6 * float(out.abs().max()))
