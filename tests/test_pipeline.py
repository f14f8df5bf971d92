"""The default pipeline: the rule's stage, then the prior stage with its data-consistency layer, counted
in steps and draws, reported per stage, the same from Python and the CLI, and explained before it runs."""

import json

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.cli import main
from pdeinv.nets.refine import PriorFit
from pdeinv.training.plan import NEGLIGIBLE, PriorStage, draw_count
from pdeinv.training.trainer import Trainer
from pdeinv.training.trainset import N_TEST


def test_python_and_the_cli_run_the_same_default_stages():
    from argparse import Namespace

    from pdeinv.cli.commands.train import _prior_stage

    trainer = Trainer("heat_1d", "sip", steps=1, n_train=8, n_test=4)
    assert trainer.prior == PriorStage() == _prior_stage(Namespace(prior_fit=None))
    assert _prior_stage(Namespace(prior_fit=0)) is None
    assert _prior_stage(Namespace(prior_fit=50)).fit.steps == 50


def test_explain_prints_the_plan_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "never"
    assert main(["train", "heat_boxes", "--set", "n=16", "--explain", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert not out.exists()
    lines = {line.split()[0] + (" " + line.split()[1] if line.startswith("stage") else ""): line
             for line in text.splitlines()}
    assert "modal" in lines["backend"] and "SpectralTikhonov" in lines["inverse"]
    assert lines["rule"].startswith("rule      sip: 30 steps")
    assert f"on {draw_count(225)} prior draws (boxes)" in lines["stage 2"]
    assert "data-consistency" in lines["stage 2"] and "GB at the peak" in lines["memory"]
    assert "stage 3" in lines and "calibration" in lines["stage 3"]
    assert main(["train", "heat_boxes", "--set", "n=16", "--explain", "--prior-fit", "0"]) == 0
    assert "stage 2   calibration" in capsys.readouterr().out  # no prior stage: calibration comes second


def test_a_run_says_its_plan_in_one_line_before_it_starts(tmp_path, capsys):
    """The stages and their counts, before the first step (a long default run is never mute)."""
    from pdeinv.training.plan import plan

    p = pdeinv.load_problem("heat_1d", n=16)
    assert plan(p, "sip", steps=2, prior=PriorStage(PriorFit(steps=3))).summary() == (
        f"plan: sip 2 steps of 1024 rows -> prior (unless the rule is within {NEGLIGIBLE:g}): at most 3 "
        f"steps on {draw_count(15)} draws -> calibration: 4096 held-out draws")
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0",
                 "--out", str(tmp_path / "r")]) == 0
    lines = capsys.readouterr().err.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("pdeinv train: plan: "))
    assert lines[first] == ("pdeinv train: plan: sip 2 steps of 1024 rows -> calibration: 4096 held-out "
                            "draws (--explain: why)")
    assert not any("step 1/" in line for line in lines[:first])


def test_the_plan_prices_what_the_guard_checks():
    """One size model: the plan's memory is the guard's estimate of that same run, with the stage's draws."""
    from pdeinv.training.plan import plan, run_bytes

    p = pdeinv.load_problem("heat_boxes", n=16)
    chosen = plan(p, "sip")
    assert chosen.memory == run_bytes(p, 1024, N_TEST, 1024, None, "default", "sip", 128, draw_count(p.N),
                                    "sgd")
    assert plan(p, "sip", prior=None).memory["data"] < chosen.memory["data"]


def test_a_rule_already_within_the_negligible_error_skips_the_stage_before_drawing():
    """Noise-free heat_1d: SIP's linear estimate is ~0.004 from the truth; the stage says why it does not
    run, from 64 pilot draws, and the network stays the rule's."""
    res = pdeinv.train(pdeinv.load_problem("heat_1d", n=16), "sip", n_train=256, n_test=32, progress=False)
    rule, prior, _ = res.metrics["stages"]
    assert rule["name"] == "sip" and rule["x_err"] < NEGLIGIBLE
    assert prior["name"] == "prior" and not prior["kept"] and "too little is left" in prior["skipped"]
    assert not bool(res.model.active)


def test_the_prior_stage_is_the_same_for_the_same_seed():
    """Counts, never clocks: two runs give bitwise the same network and errors."""
    p = pdeinv.load_problem("heat_boxes", n=8)
    runs = [pdeinv.train(p, "sip", n_train=128, n_test=16, progress=False,
                         prior=PriorStage(PriorFit(steps=30), draws=256)) for _ in range(2)]
    a, b = (r.model.state_dict() for r in runs)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert runs[0].metrics["x_err"] == runs[1].metrics["x_err"]
    assert 0 < runs[0].metrics["stages"][1]["steps"] <= 30


@pytest.mark.slow
def test_the_default_pipeline_on_a_ci_sized_box_scene(tmp_path, capsys):
    """heat_boxes at 16×16 (225 unknowns), every stage on, the stage's fit cut to 600 steps for CI time
    (its default count is ~9 000; docs/train.md): SIP's linear estimate ~0.37, the prior stage below 0.28,
    and the final estimate reproduces the noise-free observations to 1e-6."""
    out = tmp_path / "run"
    assert main(["train", "heat_boxes", "--set", "n=16", "--prior-fit", "600", "--out", str(out),
                 "--export-samples", "0"]) == 0
    line = capsys.readouterr().out
    m = json.loads((out / "metrics.json").read_text())
    rule, prior, _ = m["stages"]
    assert (rule["name"], prior["name"]) == ("sip", "prior") and prior["kept"]
    assert 0.30 < rule["x_err"] < 0.45 and rule["y_err"] < 1e-9
    assert prior["x_err"] < 0.28 and prior["y_err"] < 1e-6 and prior["draws"] == draw_count(225)
    assert m["x_err"] == prior["x_err"] and m["y_err"] == prior["y_err"]
    assert "sip: 30 steps" in line and "prior: 600 steps on 65536 draws" in line


@pytest.mark.slow
def test_with_noise_the_final_estimate_fits_the_observations_to_the_noise_level(tmp_path):
    p = pdeinv.load_problem("heat_boxes", n=16, noise=0.01)
    res = pdeinv.train(p, "sip", progress=False, prior=PriorStage(PriorFit(steps=400), draws=8192))
    rule, prior, _ = res.metrics["stages"]
    assert prior["kept"] and prior["x_err"] < rule["x_err"]
    assert prior["y_err"] <= 1.5 * 0.01
    assert np.isfinite(prior["error_after"]) and prior["error_after"] <= prior["error_corrected"] * 1.01


@pytest.mark.slow
def test_the_rule_decides_what_the_data_resolve():
    """The prior stage changes only the modes the data cannot decide: Adam's network keeps Adam's answer (and
    its misfit) where the data decide, SIP's keeps SIP's, so the final estimates stay as far apart as the
    rules made them (heat_boxes 16×16 noise-free: SIP 0.23, Adam 0.78 with this stage)."""
    p = pdeinv.load_problem("heat_boxes", n=16)
    stage = PriorStage(PriorFit(steps=200), draws=4096)
    runs = {r: pdeinv.train(p, r, progress=False, prior=stage).metrics["stages"] for r in ("sip", "adam")}
    sip_prior, (adam, adam_prior) = runs["sip"][1], runs["adam"][:2]
    assert sip_prior["kept"] and adam_prior["kept"]
    assert sip_prior["x_err"] <= 0.5 * adam_prior["x_err"]
    assert sip_prior["y_err"] < 1e-9  # SIP fits the data, so the final estimate does
    assert adam_prior["y_err"] == pytest.approx(adam["y_err"], rel=1e-6)  # Adam's misfit is Adam's


@pytest.mark.parametrize("flags, says", [
    (["--n-train", "0"], "--n-train 0 is not allowed"),
    (["--n-test", "0"], "--n-test 0 is not allowed"),
    (["--net", "modal", "--hidden", "8,8"], "choose two networks"),
    (["--time-budget", "0"], "--time-budget 0"),
    (["--hidden", "99999999999"], "of memory, above the budget"),
])
def test_explain_refuses_what_the_run_refuses(flags, says, capsys, tmp_path):
    """A plan of a run that would be refused is no plan: the run's checks, the same line, exit 2."""
    assert main(["train", "heat_1d", "--set", "n=16", "--explain", *flags]) == 2
    assert says in capsys.readouterr().err
    out = tmp_path / "run"
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--out", str(out),
                 *flags]) == 2
    assert says in capsys.readouterr().err and not out.exists()


def test_a_time_budget_of_no_seconds_is_refused_in_python_too():
    with pytest.raises(ValueError, match="time_budget"):
        Trainer("heat_1d", "sip", steps=1, n_train=8, n_test=4, time_budget=0)
