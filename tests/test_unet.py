"""The U-Net the rules train end to end (pdeinv.nets.unet, ``--net unet``): sizes, determinism, its
inputs, derivatives, the presets it gets, and a training regression of the SIP paper's claim (SIP's
proxy step trains it further than Adam on the same steps)."""

import json

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.cli import main
from pdeinv.methods.presets import SIP_MLP, run_defaults
from pdeinv.nets import MeshUNet, network_size, unet
from pdeinv.nets.refine import PriorFit
from pdeinv.nets.unet import inputs
from pdeinv.training.plan import PriorStage


@pytest.fixture(scope="module")
def boxes():
    return pdeinv.load_problem("heat_boxes", n=16)


def _params(net):
    return sum(p.numel() for p in net.parameters())


def test_parameters_do_not_grow_with_the_mesh_and_the_size_model_is_exact(boxes):
    bare = unet(refine=False)
    small, large = bare(boxes), bare(pdeinv.load_problem("heat_boxes", n=24))
    assert _params(small) == _params(large)
    size = network_size(boxes, "unet")  # with the prior stage's correction: an upper bound
    assert _params(small) < size["params"] and _params(unet()(boxes)) <= size["params"]
    buffers = sum(b.numel() for b in small.state_dict().values()) - _params(small)
    assert buffers <= size["buffers"]


def test_initialisation_is_seeded_and_starts_at_zero(boxes):
    torch.manual_seed(3)
    a = unet(refine=False)(boxes)
    torch.manual_seed(3)
    b = unet(refine=False)(boxes)
    for (ka, va), (kb, vb) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert ka == kb and torch.equal(va, vb)
    y = torch.as_tensor(boxes.sample(4, seed=1)[1])
    a.fit_observations(y)
    assert torch.count_nonzero(a(y)) == 0  # the zero last layer: the paper's form starts at 0


def test_residual_form_starts_at_the_physics_estimate(boxes):
    net = unet(residual=True, refine=False)(boxes)
    y = torch.as_tensor(boxes.sample(4, seed=2)[1])
    net.fit_observations(y)
    x_t = net.physics(y)
    assert torch.allclose(net(y).double(), x_t, rtol=1e-6, atol=1e-6 * float(x_t.abs().max()))
    # noise-free, that estimate already reproduces the observations (why residual is not the default)
    y_t = boxes.operator.forward(x_t.numpy())
    assert np.linalg.norm(y_t - y.numpy()) <= 1e-6 * np.linalg.norm(y.numpy())


def test_inputs_are_what_the_physics_offers(boxes):
    assert inputs(boxes) == 2  # the final state lives on the unknowns, and the modal basis gives x_T
    sensors = pdeinv.load_problem("heat_sensors_2d", n=12)
    assert sensors.operator.n_out != sensors.N and inputs(sensors) <= 1  # no observation channel
    with pytest.raises(ValueError, match="needs the physics estimate it adds to"):
        MeshUNet(unet(refine=False)(boxes).grid, None, True, residual=True)


def test_one_sample_and_a_batch_agree_and_gradcheck_in_float64():
    boxes = pdeinv.load_problem("heat_boxes", n=16, noise=0.05)  # x_T amplifies by at most 1/noise
    torch.manual_seed(0)
    net = unet(channels=4, refine=False)(boxes).double()
    torch.nn.init.normal_(net.unet.out.weight, std=0.1)  # a nonzero output, so the check sees the layers
    y = torch.as_tensor(boxes.sample(2, seed=4)[1])
    net.fit_observations(y)
    assert torch.allclose(net(y[0]), net(y)[0], atol=1e-12)
    yq = y[:1].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(net, (yq,), fast_mode=True, eps=1e-6, atol=1e-5)


def test_presets_for_a_network_not_linear_in_its_parameters(boxes):
    net = unet()(boxes)  # the refined network declares what its U-Net base declares
    sip = run_defaults(pdeinv.SIP(), net, boxes)
    assert (sip["batch_size"], sip["steps"]) == (SIP_MLP["batch_size"], SIP_MLP["steps"])
    trainer = pdeinv.Trainer(boxes, "sip", model=net, prior=None)
    assert trainer.batch_size == SIP_MLP["batch_size"] and trainer.rule.normalize is False
    plan = pdeinv.plan(boxes, "hig", net="unet")
    assert "matrix-free" in plan.explain() and plan.network["params"] >= _params(net)
    assert "Kronecker" in pdeinv.plan(boxes, "hig").explain()


def test_sip_trains_the_unet_further_than_adam_on_the_same_steps(boxes):
    """The SIP paper's heat claim in CI size: the same U-Net, initialisation, rows and 60 minibatch steps;
    x never enters a loss. Measured (n = 16, 256 rows, one thread): SIP 0.622, Adam 0.897 (0.69×); on 1024
    rows at 150 steps 0.475 against 0.811 (0.59×). The SIP paper reports 0.40× on its 64² version."""
    errs = {}
    for method in ("sip", "adam"):
        torch.manual_seed(0)
        r = pdeinv.train(boxes, method, model=unet(refine=False)(boxes), prior=None, steps=60, progress=False,
                         eval_every=60, n_train=256, n_test=64)
        errs[method] = r.metrics["x_err"]
    assert errs["sip"] <= 0.8 * errs["adam"], errs
    assert errs["sip"] < 0.7, errs


def test_cli_trains_saves_and_reloads_the_unet(tmp_path):
    out = tmp_path / "run"
    assert main(["train", "heat_boxes", "--set", "n=12", "--net", "unet", "--steps", "3", "--n-train", "64",
                 "--n-test", "16", "--prior-fit", "0", "--out", str(out), "-q", "--export-samples", "0"]) == 0
    run = json.loads((out / "run.json").read_text())
    assert run["network"]["kind"] == "unet"
    assert (out / "model.pt").stat().st_size < 2_000_000  # sized by its parameters, not by the mesh
    metrics = json.loads((out / "metrics.json").read_text())
    _, model = pdeinv.load_run(out)
    x, y = pdeinv.load_problem("heat_boxes", n=12).sample(4, seed=9)
    with torch.no_grad():
        assert model(torch.as_tensor(y, dtype=torch.float32)).shape == (4, x.shape[1])
    assert metrics["stages"][0]["name"] == "sip"
    depth = unet(refine=False)(pdeinv.load_problem("heat_boxes", n=12)).unet.levels
    assert (run["network"]["depth"], run["network"]["up_convs"]) == (depth, 2)  # what reloads it


def test_the_depth_follows_the_grid_down_to_a_few_points_per_axis():
    """``levels``: as many halvings as keep COARSEST points per axis (stride-2 convolutions round up), at
    most LEVELS: the SIP paper's four on its 64² grid."""
    from pdeinv.nets.unet import COARSEST, LEVELS, levels

    assert levels((65, 65)) == levels((63, 63)) == 4 == LEVELS and levels((33, 40)) == 3
    assert levels((17,)) == 2 and levels((9, 9, 9)) == 1 and levels((5, 5)) == 0
    for side in range(2, 300):
        d, coarsest = levels((side,)), side
        for _ in range(d):
            coarsest = (coarsest + 1) // 2
        assert coarsest >= COARSEST or d == 0
        assert d == LEVELS or (coarsest + 1) // 2 < COARSEST  # no further halving would keep enough


@pytest.mark.parametrize("dim,levels,up", [(1, 3, 2), (2, 2, 1), (2, 4, 2), (3, 2, 2)])
def test_the_multiply_add_count_is_what_the_convolutions_do(dim, levels, up):
    """``unet_macs`` (the plan's cost model) against the convolutions' own count on a grid whose every
    level halves exactly: weights per output point times the output points of each."""
    from pdeinv.nets import corrections

    net, side = corrections.UNet(dim, 4, 2, levels, up), 2 ** (levels + 2)
    macs = []
    hooks = [m.register_forward_hook(lambda m, i, o: macs.append(o[0].numel() * m.weight[0].numel()))
             for m in net.modules() if isinstance(m, torch.nn.modules.conv._ConvNd)]
    net(torch.zeros(1, 2, *(side,) * dim))
    for h in hooks:
        h.remove()
    assert corrections.unet_macs(side**dim, dim, 4, 2, levels, up) == sum(macs)


def test_a_run_saved_before_the_depth_was_recorded_loads_as_the_two_level_net(tmp_path):
    """run.json's ``{"kind": "unet"}`` without ``depth``: the two-level, one-convolution-up U-Net of those
    runs, its state dict under the old names (``e1 … u1``), the same function as before."""
    from pdeinv.io import runs

    problem = pdeinv.load_problem("heat_boxes", n=12)
    torch.manual_seed(0)
    old = unet(depth=2, up_convs=1)(problem)
    torch.nn.init.normal_(old.base.unet.out.weight if hasattr(old, "base") else old.unet.out.weight, std=0.1)
    out = pdeinv.save_run(tmp_path / "run", "heat_boxes", {"n": 12}, {"kind": "unet"}, model=old)
    record = json.loads((out / "run.json").read_text())
    assert (record["network"]["depth"], record["network"]["up_convs"]) == (2, 1)
    legacy = {"e1.": "down.0.", "e2.": "down.1.", "e3.": "down.2.", "u2.": "up.1.", "u1.": "up.0."}
    state = {}
    for k, v in torch.load(out / "model.pt").items():
        for a, b in legacy.items():
            k = k.replace("unet." + b, "unet." + a)
        state[k] = v
    assert any(".unet.e1." in k or k.startswith("unet.e1.") for k in state)
    torch.save(state, out / "model.pt")
    del record["network"]["depth"], record["network"]["up_convs"]
    record["model_sha256"] = __import__("hashlib").sha256((out / "model.pt").read_bytes()).hexdigest()
    record["record_sha256"] = runs._record_digest(record)
    (out / "run.json").write_text(json.dumps(record))
    _, model = pdeinv.load_run(out)
    y = torch.as_tensor(problem.sample(3, seed=5)[1], dtype=torch.float32)
    with torch.no_grad():
        torch.testing.assert_close(model(y), old(y))


def test_fresh_draws_are_seeded_per_step_and_reported(boxes):
    """``fresh=True`` (the paper's protocol): each step new draws; the same seed gives the same model, and
    the rule's stage says how many draws it saw."""
    from pdeinv.training.trainset import fresh_rows

    a, b = fresh_rows(boxes, 4, 0, 1), fresh_rows(boxes, 4, 0, 2)
    assert not np.allclose(a, b) and np.array_equal(a, fresh_rows(boxes, 4, 0, 1))
    runs = []
    for _ in range(2):
        torch.manual_seed(0)
        r = pdeinv.train(boxes, "sip", model=unet(channels=4, refine=False)(boxes), prior=None, steps=3,
                         progress=False,
                         n_train=64, n_test=16, fresh=True)
        runs.append(r)
    stage = runs[0].metrics["stages"][0]
    assert stage["data"] == "fresh" and stage["draws"] == 3 * SIP_MLP["batch_size"]
    assert runs[0].metrics["x_err"] == runs[1].metrics["x_err"]
    with pytest.raises(ValueError, match="fresh=True draws new observations"):
        pdeinv.Trainer(boxes, "sip", prior=None, data=boxes.sample(40, seed=1)[1], n_test=8, fresh=True)
    with pytest.raises(TypeError, match="fresh"):
        pdeinv.Trainer(boxes, "sip", prior=None, fresh="yes")


def test_the_prior_stage_adds_to_the_rule_trained_unet(boxes):
    """``--net unet`` with a prior: the rule trains the U-Net, then the prior stage fits its correction and
    data-consistency layer on top (the pipeline's stage 2), in the modes the data cannot decide only: the
    U-Net's answer where they decide is the rule's, and so is its misfit (30 steps: x-error 0.857 -> 0.846,
    y-error unchanged)."""
    torch.manual_seed(0)
    r = pdeinv.train(boxes, "sip", model=unet()(boxes), steps=30, progress=False, n_train=256, n_test=32,
                     prior=PriorStage(PriorFit(steps=150), draws=2048))
    rule, prior, _ = r.metrics["stages"]
    assert prior["name"] == "prior" and prior["kept"], prior
    assert prior["x_err"] < rule["x_err"] and prior["y_err"] == pytest.approx(rule["y_err"], rel=1e-3), \
        (rule, prior)


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_a_large_batch_goes_through_in_chunks_with_each_row_as_alone(dim, monkeypatch):
    """Batches beyond POINTS grid points are applied in chunks of rows: every row's output is what that
    row gives alone, and the gradient flows through the chunks."""
    from pdeinv.nets import corrections

    torch.manual_seed(0)
    g = corrections.UNet(dim, 4, 2).double()
    for q in g.out.parameters():
        torch.nn.init.normal_(q)
    shape = (12,) * dim
    monkeypatch.setattr(corrections, "POINTS", 2 * 12**dim)  # chunks of 2 rows
    x = torch.randn(5, 2, *shape, dtype=torch.float64, requires_grad=True)
    out = g(x)
    alone = torch.cat([g(x[i:i + 1]) for i in range(5)])
    torch.testing.assert_close(out, alone, rtol=1e-12, atol=1e-12)
    out.sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
