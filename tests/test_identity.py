"""A checkpoint's identity covers every hyper-parameter of the rule and of the network: resuming with
another lr, η, τ, width, activation or whitening floor is refused naming the key and both values, while
--steps may grow and the step size the non-finite guard lowered during the run is not a mismatch."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from torch import nn

import pdeinv
from pdeinv import Checkpoint, Trainer
from pdeinv.cli import main
from pdeinv.methods import GD, HIG, SIP, adam, sgd
from pdeinv.nets import MLP, whitened

FAULTS = str(Path(__file__).with_name("faults.py"))
SMALL = ["--set", "n=16", "--set", "steps=10", "--hidden", "8", "--n-train", "32", "--n-test", "8",
         "--batch-size", "8", "--threads", "1", "--export-samples", "0", "--checkpoint-every", "1"]


pytestmark = pytest.mark.usefixtures("one_thread")  # small dense work: one torch thread


def trainer(problem, rule, steps, ckpt, resume=False, model=None, **kw):
    torch.manual_seed(0)
    model = model or MLP(problem.operator.n_out, problem.operator.n_in, hidden=(16,))
    return Trainer(problem, rule, model, steps=steps, n_train=24, n_test=16, batch_size=8, eval_every=4,
                   progress=False, checkpoint=ckpt, resume=resume, **kw)


def refused(problem, saved_with, resumed_with, tmp_path, **kw):
    """Train 2 steps with ``saved_with``, resume with ``resumed_with``: the ValueError's message."""
    tmp_path.mkdir(exist_ok=True)
    ckpt = Checkpoint(tmp_path / "c.pt", every=1)
    trainer(problem, saved_with, 2, ckpt, **kw.pop("saved", {})).fit()
    before = ckpt.path.read_bytes()
    with pytest.raises(ValueError) as err:
        trainer(problem, resumed_with, 4, ckpt, resume=True, **kw.pop("resumed", {})).fit()
    assert ckpt.path.read_bytes() == before  # a refused run leaves the checkpoint alone
    return str(err.value)


@pytest.mark.parametrize("saved, resumed, named", [
    (GD(adam(1e-2)), GD(adam(1e-5)), "lr=0.01 (checkpoint) vs 1e-05 (this run)"),
    (GD(sgd(0.1)), GD(sgd(0.1, momentum=0.9)), "momentum=0 (checkpoint) vs 0.9 (this run)"),
    (GD(adam(1e-3)), GD(sgd(1e-3)), "optimizer='Adam' (checkpoint) vs 'SGD' (this run)"),
    (SIP(eta=1.0), SIP(eta=0.5), "eta=1.0 (checkpoint) vs 0.5 (this run)"),
    (HIG(tau=1e-5), HIG(tau=1e-6), "tau=1e-05 (checkpoint) vs 1e-06 (this run)"),
    (HIG(route="svd"), HIG(route="gram"), "route='svd' (checkpoint) vs 'gram' (this run)"),
], ids=["lr", "momentum", "optimizer", "sip-eta", "hig-tau", "hig-route"])
def test_another_rule_hyperparameter_is_refused_naming_both(heat, tmp_path, saved, resumed, named):
    message = refused(heat, saved, resumed, tmp_path)
    assert f"with rule {saved.name!r} and other hyper-parameters: {named}" in message


def test_another_network_width_activation_or_whitening_is_refused_naming_both(heat, tmp_path):
    n_in, n_out = heat.operator.n_out, heat.operator.n_in
    net = lambda **kw: {"model": MLP(n_in, n_out, **{"hidden": (16,), **kw})}  # noqa: E731
    message = refused(heat, GD(), GD(), tmp_path, saved=net(), resumed=net(hidden=(8,)))
    assert "body.0.out_features=16 (checkpoint) vs 8 (this run)" in message
    message = refused(heat, GD(), GD(), tmp_path / "a", saved=net(), resumed=net(activation=nn.ReLU))
    assert "body.1='Tanh' (checkpoint) vs 'ReLU' (this run)" in message  # same shapes: only the class differs
    white = lambda floor: {"model": whitened("linear", rel_floor=floor)(heat)}  # noqa: E731
    message = refused(heat, GD(), GD(), tmp_path / "w", saved=white(1e-3), resumed=white(1e-2))
    assert "pre.rel_floor=0.001 (checkpoint) vs 0.01 (this run)" in message


def test_more_steps_and_a_guard_lowered_step_size_are_no_mismatch(tmp_path):
    """A poisoned step halves the lr during the run; resuming with the same configuration is accepted,
    keeps the halved lr and repeats the uninterrupted run bitwise."""
    problem = lambda: pdeinv.load_problem(FAULTS, poison="3", n=16, steps=10)  # noqa: E731
    ref = trainer(problem(), GD(sgd(0.05)), 7, None)
    with pytest.warns(RuntimeWarning, match="scaled by 0.5"):
        ref = ref.fit()
    ckpt = Checkpoint(tmp_path / "c.pt", every=1)
    with pytest.warns(RuntimeWarning, match="scaled by 0.5"):
        first = trainer(problem(), GD(sgd(0.05)), 5, ckpt).fit()
    assert first.state.transform.param_groups[0]["lr"] == 0.025
    assert ckpt.load()["guard"]["scale"] == 0.5
    # more steps: accepted (a fresh faults problem poisons its 3rd call again: resume for two steps)
    longer = trainer(problem(), GD(sgd(0.05)), 7, ckpt, resume=True).fit()
    assert longer.state.transform.param_groups[0]["lr"] == 0.025  # the lowered step size survives
    assert [repr(h["loss"]) for h in longer.history] == [repr(h["loss"]) for h in ref.history]  # NaN too
    assert longer.metrics["steps"] == 7 and longer.metrics["rejected_steps"] == 1


def test_cli_refuses_another_lr_with_exit_2_and_extends_steps(tmp_path, capsys):
    out = str(tmp_path / "run")
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--method", "adam", "--lr", "1e-2", "--steps", "2", *SMALL,
                 "--out", out]) == 0
    before = (tmp_path / "run" / "checkpoint.pt").read_bytes()
    capsys.readouterr()
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--method", "adam", "--lr", "1e-5", "--steps", "4", *SMALL,
                 "--out", out, "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pdeinv train: error: ") and "lr=0.01 (checkpoint) vs 1e-05 (this run)" in err
    assert (tmp_path / "run" / "checkpoint.pt").read_bytes() == before
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--method", "sip", "--eta", "0.5", "--steps", "4", *SMALL,
                 "--out", out, "--resume"]) == 2
    assert "rule 'adam'; this run has 'sip'" in capsys.readouterr().err
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--method", "adam", "--lr", "1e-2", "--steps", "4", *SMALL,
                 "--out", out, "--resume"]) == 0
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["steps"] == 4


def test_cli_refuses_another_sip_eta(tmp_path, capsys):
    out = str(tmp_path / "run")
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--method", "sip", "--steps", "2", *SMALL, "--out", out]) == 0
    capsys.readouterr()
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--method", "sip", "--eta", "0.5", "--steps", "4", *SMALL,
                 "--out", out, "--resume"]) == 2
    assert "eta=1.0 (checkpoint) vs 0.5 (this run)" in capsys.readouterr().err
