"""The guard: a bad step (NaN/Inf, or a loss beyond ``max_loss_growth`` × the lowest so far) is
rejected, the last good state (parameters and optimizer from before the previous update, whose loss
was the last to pass) is put back, the step size is multiplied by ``step_factor`` (½), training goes
on; ``max_failures`` consecutive rejections stop it with a message naming the step, the last good
state and the last checkpoint, which stays intact."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch
from stderr import said

import pdeinv
from pdeinv import Checkpoint, Trainer
from pdeinv.cli import main
from pdeinv.methods import GD, HIG, SIP, NonFiniteError, adam, apply_if_finite, sgd
from pdeinv.nets import MLP
from pdeinv.training.checkpoint import history_rows

FAULTS = str(Path(__file__).with_name("faults.py"))


pytestmark = pytest.mark.usefixtures("one_thread")  # small dense work: one torch thread


def trainer(rule, poison="", steps=6, **kw):
    problem = pdeinv.load_problem(FAULTS, poison=poison, n=16, steps=10)
    torch.manual_seed(0)
    model = MLP(problem.operator.n_out, problem.operator.n_in, hidden=(16,))
    kw.setdefault("snapshot_every", 1)  # the exact one-step roll-back these tests trace (tests/test_guard.py)
    return Trainer(problem, rule, model, steps=steps, n_train=32, n_test=16, batch_size=8, eval_every=100,
                   progress=False, **kw)


def snapshots(into: dict):
    """A callback keeping a copy of the parameters after every accepted step."""
    return lambda rec, model: into.__setitem__(rec["step"], [p.detach().clone() for p in model.parameters()])


@pytest.mark.parametrize("rule", [GD(sgd(0.05)), SIP(optimizer=adam(1e-3))], ids=["gd", "sip"])
def test_a_poisoned_step_is_rejected_the_lr_halved_and_training_continues(rule):
    t = trainer(rule, poison="3")
    with pytest.warns(RuntimeWarning, match=r"step 3 \(.*\): .*not finite.*step size scaled by 0.5"):
        r = t.fit()
    steps = [(h["step"], "rejected" in h) for h in r.history]
    # step 3's loss is that of step 2's parameters: not trusted, step 2 is undone and redone
    assert steps == [(1, False), (2, False), (3, True), (2, False), (3, False), (4, False), (5, False),
                     (6, False)]
    assert math.isnan(r.history[2]["loss"]) and all(math.isfinite(h["loss"]) for h in r.history if
                                                    "rejected" not in h)
    assert r.metrics["steps"] == 6 and r.metrics["rejected_steps"] == 1
    opt = r.state.transform  # the rule's transformation state: its torch optimizer
    base = 0.05 if rule.name == "gd" else 1e-3
    assert opt.param_groups[0]["lr"] == pytest.approx(0.5 * base)
    if rule.name == "sip":  # Adam's moments rolled back with the parameters: 6 surviving steps
        assert all(int(s["step"]) == 6 for s in opt.state.values())


def test_rejected_step_leaves_the_parameters_of_the_last_good_step():
    kept = {}
    t = trainer(GD(adam(1e-3)), poison="4", max_failures=1, callbacks=[snapshots(kept)])
    with pytest.raises(NonFiniteError, match=r"^step 4 \(gd\): .*not finite.*max_failures=1\); "
                                             r"the model holds the last good state \(after step 2\)"):
        t.fit()
    assert sorted(kept) == [1, 2, 3]
    # step 4's loss was that of step 3's parameters: the last verified ones are step 2's
    assert all(torch.equal(a, b) for a, b in zip(kept[2], t.model.parameters()))


def test_hig_scale_step_scales_its_update():
    deltas = []
    for factor in (1.0, 0.5):
        t = trainer(HIG(eta=0.1, tau=1e-5))
        model = t.model
        rule = t.rule
        state = rule.init(t.problem, model)
        before = [p.detach().clone() for p in model.parameters()]
        y = torch.as_tensor(t.problem.sample(8, 0)[1], dtype=torch.float32)
        apply_if_finite(rule, state, model, y, scale=factor)  # the guard's step-size multiplier
        deltas.append(torch.cat([(p.detach() - b).ravel() for p, b in zip(model.parameters(), before)]))
    assert torch.linalg.norm(deltas[0]) > 0
    torch.testing.assert_close(deltas[1], 0.5 * deltas[0], rtol=1e-5, atol=1e-8)


def test_consecutive_failures_stop_with_the_last_good_checkpoint(tmp_path):
    ckpt = Checkpoint(tmp_path / "c.pt", every=1)
    t = trainer(GD(adam(1e-3)), poison="3,4,5", max_failures=3, checkpoint=ckpt)
    with pytest.warns(RuntimeWarning), pytest.raises(
            NonFiniteError, match=r"step 2 \(gd\).*3 consecutive rejected steps \(max_failures=3\); "
                                  r"the model holds the last good state \(after step 1\); "
                                  r"last good checkpoint: '.*c\.pt' \(step 2\)"):
        t.fit()
    saved = ckpt.load()
    assert saved["position"]["step"] == 2 and [h["step"] for h in history_rows(saved["history"])] == [1, 2]
    # failures with progress in between do not add up: call 2 rejects step 2 (back to step 0), call 3
    # redoes step 1, call 4 passes step 2 (new parameters: the streak ends), call 5 rejects step 3.
    # (Poison "2,4" would reject step 2 twice in a row: a re-accepted step 1 is no progress.)
    with pytest.warns(RuntimeWarning):
        r = trainer(GD(adam(1e-3)), poison="2,5", max_failures=2).fit()
    assert r.metrics["steps"] == 6 and r.metrics["rejected_steps"] == 2


def test_cli_gives_up_with_one_line_and_keeps_the_checkpoint(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "--prior-fit", "0",
            FAULTS, "--method", "adam", "--set", "n=16", "--set", "steps=10", "--hidden", "16",
            "--n-train", "32", "--n-test", "16", "--batch-size", "8", "--steps", "8",
            "--checkpoint-every", "1", "--out", str(out), "--threads", "1"]
    code = main([*argv, "--set", "poison=4,5,6", "--max-failures", "3"])
    *warned, err = said(capsys.readouterr().err)
    # the default guard copies its last good state every 10th step: step 4 rolls back to step 0's
    assert code == 1 and err.startswith("pdeinv train: numerical failure: step 1 (adam)")
    assert "last good checkpoint" in err and "checkpoint.pt" in err and "(after step 0)" in err
    assert [w[:40] for w in warned] == ["pdeinv train: warning: step 4 (adam): th",  # one line each
                                        "pdeinv train: warning: step 1 (adam): th"]
    assert Checkpoint(out / "checkpoint.pt").load()["position"]["step"] == 3
    assert not (out / "metrics.json").exists()
    assert "rejected" in (out / "history.csv").read_text()
    # the same run without the fault, resumed from the surviving checkpoint, is refused: the
    # settings differ (poison) -- and with the same settings it resumes and finishes
    assert main([*argv, "--set", "poison=", "--resume"]) == 2
    assert "poison='4,5,6' (checkpoint) vs '' (this run)" in capsys.readouterr().err
    # max_failures=5 lets this run through the three bad calls (step 7, then, back at the checkpoint's
    # last good state after step 0, step 1 twice)
    assert main([*argv, "--set", "poison=4,5,6", "--resume"]) == 0
    err = capsys.readouterr().err
    assert err.count("warning: step 7 (adam)") == 1 and err.count("warning: step 1 (adam)") == 2
    assert json.loads((out / "metrics.json").read_text())["steps"] == 8
