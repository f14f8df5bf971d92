"""Bad and odd inputs of the fourteenth round (issue 48), and what round thirteen left: observations in
float16, bfloat16 or float32 through the API (the rounding is noise the problem does not declare: the CLI
trains with it, the API says so), a half-precision network, a user's setting holding an object that
compares by identity (a new one each ``make()``). Each failed on the code before."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.problem.trained import differ

KW = dict(steps=2, n_test=16, prior=None, calibration=None)


@pytest.mark.parametrize("cast, level", [
    (lambda y: y.astype(np.float16), 2.0**-11),
    (lambda y: torch.tensor(y, dtype=torch.bfloat16), 2.0**-8),
    (lambda y: torch.tensor(y, dtype=torch.float32), 2.0**-24),
])
def test_api_data_in_low_precision_names_its_rounding_noise(cast, level):
    p = pdeinv.load_problem("heat_1d", n=16)
    _, y = p.sample(80, seed=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pdeinv.Trainer(p, "sip", data=cast(y), **KW)
    said = [str(w.message) for w in caught if "rounding" in str(w.message)]
    assert len(said) == 1 and f"noise={level:.2g}" in said[0], said


def test_api_float64_data_and_a_noisy_problem_say_nothing_of_rounding():
    p = pdeinv.load_problem("heat_1d", n=16, noise=0.01)
    _, y = p.sample(80, seed=1)
    for data in (y, y.astype(np.float32)):  # 6e-8 is far below the declared 1 %
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            pdeinv.Trainer(p, "sip", data=data, **KW)
        assert not [w for w in caught if "rounding" in str(w.message)]


@pytest.mark.parametrize("low", [torch.float16, torch.bfloat16])
def test_a_half_precision_network_is_refused_before_training(low):
    p = pdeinv.load_problem("heat_1d", n=16)
    m = torch.nn.Linear(p.operator.n_out, p.N).to(low)
    with pytest.raises(ValueError, match=rf"model has {low} parameters; expected torch.float32"):
        pdeinv.train(p, "adam", m, n_train=64, **KW)


class _Plain:
    pass


def test_settings_that_compare_by_identity_are_compared_by_class():
    assert not differ(_Plain(), _Plain())
    assert differ(_Plain(), object())
    assert differ(1, 2) and not differ(np.arange(3), np.arange(3)) and differ(np.arange(3), np.ones(3))


def test_a_user_setting_holding_an_object_trains_and_saves(tmp_path, monkeypatch, capsys):
    from pdeinv.cli import main

    (tmp_path / "rod.py").write_text(
        "import dataclasses\nimport pdeinv\n\nclass Odd:\n    pass\n\n"
        "def make(**kw):\n    p = pdeinv.load_problem('heat_1d', n=16, **kw)\n"
        "    return dataclasses.replace(p, settings={**p.settings, 'odd': Odd()})\n")
    monkeypatch.chdir(tmp_path)
    assert main(["train", "rod.py", "--steps", "2", "--n-train", "32", "--n-test", "8", "--prior-fit", "0",
                 "--threads", "1", "-q", "--out", "run"]) == 0, capsys.readouterr().err
    assert (tmp_path / "run" / "model.pt").exists()


@pytest.mark.parametrize("units", [1e-3, 1e3, 1e6])
def test_classical_takes_y_only_data_in_other_units(tmp_path, capsys, units):
    from pdeinv.cli import main

    _, y = pdeinv.load_problem("heat_1d", n=16).sample(200, seed=2)
    np.savez(tmp_path / "y.npz", y=y * units)
    assert main(["classical", "heat_1d", "--set", "n=16", "-q", "--data", str(tmp_path / "y.npz")]) == 0, \
        capsys.readouterr().err


def test_classical_still_refuses_y_only_data_of_another_physics(tmp_path, capsys):
    from pdeinv.cli import main

    _, y = pdeinv.load_problem("wave_1d", n=16).sample(200, seed=2)
    np.savez(tmp_path / "wave.npz", y=y * 1e3)
    assert main(["classical", "heat_1d", "--set", "n=16", "-q", "--data", str(tmp_path / "wave.npz")]) == 3
    assert "per unit of the observations'" in capsys.readouterr().err


def test_adam_betas_of_the_wrong_length_is_a_named_value_error():
    with pytest.raises(ValueError, match=r"pdeinv.adam\(betas=\(0.9,\)\) is not allowed"):
        pdeinv.adam(1e-3, betas=(0.9,))


def test_a_1d_mesh_whose_build_exceeds_the_budget_is_refused_before_building():
    from pdeinv.util import memory

    memory.set_budget(10.0)  # heat_1d at n = 2·10⁶ peaks at ~12 GB building its modal basis
    try:
        with pytest.raises(memory.MemoryBudgetError, match="2e\\+06 nodes"):
            pdeinv.load_problem("heat_1d", n=2_000_000)
    finally:
        memory.set_budget(None)


def _exact_file(path):
    x, y = pdeinv.load_problem("heat_1d", n=16).sample(200, seed=2)
    np.savez(path, x=x, y=y)
    return str(path)


@pytest.mark.parametrize("command", ["train", "classical"])
def test_a_noise_level_set_far_above_what_the_files_x_show_is_refused(tmp_path, capsys, command):
    from pdeinv.cli import main

    data = _exact_file(tmp_path / "exact.npz")
    extra = ["--steps", "2", "--prior-fit", "0", "--n-test", "16", "--out", str(tmp_path / "r")] \
        if command == "train" else []
    assert main([command, "heat_1d", "--set", "n=16", "--set", "noise=0.05", "--data", data, "-q",
                 *extra]) == 3
    assert "--set noise=0.05 declares its noise, but its y differ from P x by 0" in capsys.readouterr().err


def test_predict_refuses_a_file_whose_declared_noise_its_x_contradict(tmp_path, capsys):
    from pdeinv.cli import main

    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-train", "64",
                 "--n-test", "16", "-q", "--out", str(tmp_path / "r")]) == 0
    x, y = pdeinv.load_problem("heat_1d", n=16).sample(50, seed=3)
    np.savez(tmp_path / "d.npz", x=x, y=y, noise=2.0)
    assert main(["predict", str(tmp_path / "r"), "--data", str(tmp_path / "d.npz"), "-q",
                 "--out", str(tmp_path / "p.npz")]) == 3
    assert "has a wrong noise level: it declares noise=2" in capsys.readouterr().err
    assert not (tmp_path / "p.npz").exists()


def test_fresh_draws_take_batches_larger_than_the_training_rows(tmp_path, capsys):
    from pdeinv.cli import main

    p = pdeinv.load_problem("heat_1d", n=16)
    t = pdeinv.Trainer(p, "sip", fresh=True, batch_size=128, n_train=64, steps=2, n_test=16, prior=None,
                       calibration=None)
    assert t.batch_size == 128
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-train", "64",
                 "--n-test", "16", "--fresh-draws", "--batch-size", "128", "-q", "--accept-bad",
                 "--out", str(tmp_path / "r")]) == 0, capsys.readouterr().err
    assert '"draws": 256' in (tmp_path / "r" / "metrics.json").read_text()
