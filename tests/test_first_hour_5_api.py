"""The Python API gives the CLI's one-line errors (issue 48): a ``ValueError``/``TypeError`` naming the
argument, the value and what is allowed, where the argument comes in — ``GD``/``SIP`` with a
``normalize`` that is no bool, an optimizer factory that optimizes other tensors than the model's (it
trained nothing: x_err 1.0), ``target='bogus'``; ``SIP(lr=…)`` is accepted as the CLI's ``--lr`` for sip
is. A cache limit in the environment that is no number is refused by every command, in one line."""

from __future__ import annotations

import pytest
import torch

import pdeinv
from pdeinv.cli import main
from pdeinv.methods.presets import make_rule

pytestmark = pytest.mark.usefixtures("one_thread")

QUICK = dict(steps=2, n_train=32, n_test=8, prior=None, calibration=None, progress=False)


@pytest.fixture(scope="module")
def heat():
    return pdeinv.load_problem("heat_1d", n=16, steps=10)


@pytest.mark.parametrize("rule", [pdeinv.GD, pdeinv.SIP])
def test_normalize_must_be_a_bool(rule):
    with pytest.raises(TypeError, match=r"^normalize='yes' is str; expected True or False$"):
        rule(normalize="yes")


def test_sip_takes_lr_as_the_cli_does(heat):
    cli = make_rule("sip", heat, lr=0.5)[0].hyperparameters()
    mine = pdeinv.SIP(lr=0.5).hyperparameters()
    assert mine["lr"] == cli["lr"] == 0.5 and mine == cli
    adam = pdeinv.SIP(optimizer=pdeinv.adam(), lr=1e-4, normalize=False).hyperparameters()
    assert adam["optimizer"] == "Adam" and adam["lr"] == 1e-4
    assert pdeinv.train(heat, pdeinv.SIP(lr=0.5), **QUICK).metrics["steps"] == 2
    with pytest.raises(ValueError, match=r"^lr=0 is not allowed"):
        pdeinv.SIP(lr=0)


def test_an_optimizer_over_other_tensors_is_refused(heat):
    other = torch.nn.Linear(3, 3)
    rule = pdeinv.GD(optimizer=lambda params: torch.optim.SGD(other.parameters(), lr=0.1))
    with pytest.raises(ValueError, match="not among the parameters it was given") as info:
        pdeinv.train(heat, rule, **QUICK)
    assert "\n" not in str(info.value) and "SGD" in str(info.value)


def test_an_optimizer_instance_of_the_model_still_trains(heat):
    model = heat.model()
    rule = pdeinv.GD(optimizer=torch.optim.SGD(model.parameters(), lr=1.0))
    assert pdeinv.train(heat, rule, model, **QUICK).metrics["steps"] == 2


def test_an_unknown_target_is_one_line(heat):
    with pytest.raises(ValueError, match=r"^target='bogus' is not allowed; expected 'auto', None or a target "
                                         r"strategy") as info:
        pdeinv.train(heat, "sip", target="bogus", **QUICK)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("value", ["abc", "-1", "nan"])
def test_a_cache_limit_that_is_no_number_is_refused(tmp_path, capsys, monkeypatch, value):
    monkeypatch.setenv("PDEINV_CACHE_MAX_GB", value)
    code = main(["train", "heat_1d", "--set", "n=16", "--steps", "1", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and err == (f"pdeinv train: error: PDEINV_CACHE_MAX_GB={value!r} is not allowed; "
                                 "expected a number of GB > 0 (an environment variable: unset it for the "
                                 "default 5)\n"), err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("kw, kind, needle", [
    ({"parallel": "x"}, TypeError, "parallel='x' is str; expected pdeinv.training.distributed.Single()"),
    ({"model": torch.nn.Linear(5, 16)}, ValueError, "model does not take this problem's 15 observations"),
    ({"model": torch.nn.Linear(15, 4)}, ValueError, "model maps 15 observations to shape (4,); expected 15"),
])
def test_trainer_arguments_fail_when_given_not_when_used(heat, kw, kind, needle):
    """Refused by Trainer(...) itself, in one line, before anything is drawn or trained."""
    with pytest.raises(kind) as info:
        pdeinv.Trainer(heat, "sip", **kw)
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_the_size_check_leaves_a_batchnorm_network_as_it_was(heat):
    model = torch.nn.Sequential(torch.nn.Linear(15, 15), torch.nn.BatchNorm1d(15))
    before = {k: v.clone() for k, v in model.state_dict().items()}
    pdeinv.Trainer(heat, "sip", model=model)
    assert model.training and all(torch.equal(v, model.state_dict()[k]) for k, v in before.items())


def test_an_unknown_train_keyword_names_the_argument_and_the_fix(heat):
    with pytest.raises(TypeError, match=r"^train\(\) got prior_fit: not an argument of pdeinv.Trainer "
                                        r"\(prior_fit: use prior=pdeinv.PriorStage"):
        pdeinv.train(heat, "sip", prior_fit=3)
