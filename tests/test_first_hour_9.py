"""Bad and odd inputs left open by the eighth round (issue 48): a module raising KeyboardInterrupt at
import is listed by `pdeinv problems`, optimizer settings torch refuses are named when the factory is made,
a network is saved and a posterior loaded only with the problem it belongs to, and the "does not apply"
line lists the flags a method takes. Each case failed (a stopped listing, a late error in torch's words, a
silent acceptance, a wrong list) on the code before."""

from __future__ import annotations

import re

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.io.runs import load_posterior, load_run, save_run


def test_problems_lists_a_module_raising_keyboard_interrupt(tmp_path, monkeypatch, capsys):
    (tmp_path / "kbi.py").write_text("raise KeyboardInterrupt\n")
    monkeypatch.setenv("PDEINV_PROBLEMS", str(tmp_path))
    assert main(["problems"]) == 0
    out = capsys.readouterr().out
    assert "kbi: cannot be imported (it raises KeyboardInterrupt)" in out
    assert "wave_sensors_2d:" in out  # the listing went on


@pytest.mark.parametrize("factory, kw, named", [
    (pdeinv.adam, dict(betas=(2, 3)), "betas=(2, 3)"),
    (pdeinv.adam, dict(weight_decay=-1), "weight_decay=-1"),
    (pdeinv.adam, dict(bogus=1), "bogus=1"),
    (pdeinv.sgd, dict(momentum=-1), "momentum=-1"),
])
def test_optimizer_settings_checked_when_the_factory_is_made(factory, kw, named):
    with pytest.raises(ValueError, match=re.escape(named)):
        factory(**kw)


def test_valid_optimizer_settings_build_the_optimizer():
    import torch

    p = [torch.zeros(3, requires_grad=True)]
    opt = pdeinv.adam(1e-2, betas=(0.8, 0.99))(p)
    assert opt.defaults["betas"] == (0.8, 0.99) and opt.defaults["lr"] == 1e-2


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A heat_1d n=8 network trained by SIP, saved with its posterior; wave_1d n=8 has the same sizes."""
    h = pdeinv.load_problem("heat_1d", n=8)
    result = pdeinv.Trainer(h, pdeinv.SIP(), steps=2, n_train=256, n_test=32).fit()
    run = save_run(tmp_path_factory.mktemp("run") / "h", h, model=result.model, posterior=result.posterior)
    return h, result, run


def test_save_run_refuses_another_problem_of_the_same_size(trained, tmp_path):
    h, result, _ = trained
    w = pdeinv.load_problem("wave_1d", n=8)
    assert (w.N, w.operator.n_out) == (h.N, h.operator.n_out)  # the shapes cannot tell them apart
    with pytest.raises(ValueError, match="trained on problem 'heat_1d', not on 'wave_1d'"):
        save_run(tmp_path / "w", w, model=result.model)
    with pytest.raises(ValueError, match="kappa=0.01; the problem given has kappa=0.02"):
        save_run(tmp_path / "k", "heat_1d", {"n": 8, "kappa": 0.02}, model=result.model)
    assert not (tmp_path / "w").exists() and not (tmp_path / "k").exists()


def test_load_posterior_refuses_another_problem(trained):
    h, _, run = trained
    with pytest.raises(ValueError, match="a run of problem 'heat_1d', not of 'wave_1d'"):
        load_posterior(run, pdeinv.load_problem("wave_1d", n=8))
    with pytest.raises(ValueError, match="trained with kappa=0.01; the problem given has kappa=0.02"):
        load_posterior(run, pdeinv.load_problem("heat_1d", n=8, kappa=0.02))
    own, _ = load_run(run)
    cal = load_posterior(run, own)
    assert cal is not None and np.array_equal(cal.scale, load_posterior(run, h).scale)


def test_does_not_apply_lists_the_flags_a_method_takes(capsys):
    assert main(["train", "heat_1d", "--method", "adam", "--eta", "1", "--explain"]) == 2
    err = capsys.readouterr().err
    assert "it takes batch_size (--batch-size), hidden (--hidden), lr (--lr), steps (--steps)" in err
    assert "rows_per_component" not in err
