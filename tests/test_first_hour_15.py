"""Bad and odd inputs of the fourteenth round (issue 48) that ended with exit 0 or a poor message: own data
set after the trainer was built, a Dataset of (y, x) pairs, supervised training on fresh draws, an
operator with NaN, a problem without a name, an archive holding one array twice, a WORLD_SIZE below one.
Each failed on the code before."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest
import torch
from torch.utils.data import TensorDataset

import pdeinv
from pdeinv.cli import main

KW = dict(steps=2, n_test=16, prior=None, calibration=None)


@pytest.fixture(scope="module")
def rod():
    p = pdeinv.load_problem("heat_1d", n=16)
    return p, *p.sample(80, seed=0)


def test_data_set_after_construction_is_refused_as_fit_starts(rod):
    p, _, y = rod
    t = pdeinv.Trainer(p, "sip", n_train=64, **KW)
    t.data = y
    with pytest.raises(ValueError, match=r"trainer.data was set after construction"):
        t.fit()


def test_a_dataset_of_pairs_gives_its_x_to_the_errors(rod):
    p, x, y = rod
    r = pdeinv.Trainer(p, "sip", data=TensorDataset(torch.tensor(y), torch.tensor(x)), **KW).fit()
    same = pdeinv.Trainer(p, "sip", data=y, data_x=x, **KW).fit()
    assert r.metrics["data"]["x"] is True and r.metrics["x_err"] == pytest.approx(same.metrics["x_err"])


def test_a_dataset_of_pairs_and_data_x_too_is_refused(rod):
    p, x, y = rod
    with pytest.raises(ValueError, match=r"give the fields once"):
        pdeinv.Trainer(p, "sip", data=TensorDataset(torch.tensor(y), torch.tensor(x)), data_x=x, **KW)
    with pytest.raises(ValueError, match=r"a Dataset item has 3 elements"):
        t = torch.tensor(y)
        pdeinv.Trainer(p, "sip", data=TensorDataset(t, t, t), **KW)


def test_supervised_training_on_fresh_draws_is_refused_before_a_step(rod):
    p, _, _ = rod
    with pytest.raises(ValueError, match=r"rule 'supervised' fits the true fields x of its training rows"):
        pdeinv.Trainer(p, "supervised", fresh=True, n_train=64, **KW)
    with pytest.raises(ValueError, match=r"knows the x of the training rows only"):  # the target's own
        pdeinv.train(p, "sip", fresh=True, n_train=64, target=pdeinv.methods.targets.TrueFields(), **KW)


def test_cli_supervised_with_fresh_draws_exits_2_naming_fresh_draws(tmp_path, capsys):
    code = main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-train", "64",
                 "--n-test", "16", "-q", "--method", "supervised", "--fresh-draws",
                 "--out", str(tmp_path / "r")])
    assert code == 2 and "--fresh-draws trains on new observations" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    assert main(["train", "heat_1d", "--method", "supervised", "--fresh-draws", "--explain"]) == 2
    assert "--fresh-draws trains on new observations" in capsys.readouterr().err


def test_a_matrix_with_nan_is_refused_where_it_is_built():
    a = np.eye(4)
    a[0, 0] = np.nan
    with pytest.raises(ValueError, match=r"Matrix\(A\): A has 1 NaN/Inf entries"):
        pdeinv.physics.Matrix(a)


def test_an_operator_that_returns_nan_is_named_not_the_sampler(rod):
    import dataclasses

    class Broken(pdeinv.physics.Matrix):
        def _forward(self, X):
            return np.full((len(X), self.n_out), np.nan)

    p = dataclasses.replace(rod[0], operator=Broken(np.eye(rod[0].N)), inverse_simulator=None)
    with pytest.raises(ValueError, match=r"its operator returned .* NaN/Inf observations of finite fields"):
        p.sample(4)


def test_cli_demo_of_a_module_with_a_nan_operator_exits_2(tmp_path, capsys):
    (tmp_path / "nan_op.py").write_text(
        "import dataclasses\nimport numpy as np\nimport pdeinv\n\n"
        "def make(**kw):\n    p = pdeinv.load_problem('heat_1d', n=16, **kw)\n"
        "    a = np.eye(p.N)\n    a[0, 0] = np.nan\n"
        "    return dataclasses.replace(p, operator=pdeinv.physics.Matrix(a), inverse_simulator=None)\n")
    assert main(["demo", str(tmp_path / "nan_op.py"), "--batch", "2"]) == 2
    assert "NaN/Inf entries" in capsys.readouterr().err


@pytest.mark.parametrize("name", [None, "", "  ", 3])
def test_a_problem_without_a_name_is_refused(rod, name):
    import dataclasses

    with pytest.raises(ValueError, match=r"expected a non-empty string"):
        dataclasses.replace(rod[0], name=name)


@pytest.mark.parametrize("command", ["train", "predict"])
def test_an_archive_holding_y_twice_is_refused(tmp_path, capsys, rod, command):
    _, _, y = rod
    with zipfile.ZipFile(tmp_path / "dup.npz", "w") as z, pytest.warns(UserWarning, match="Duplicate name"):
        for scale in (1.0, 1e6):
            b = io.BytesIO()
            np.save(b, y * scale)
            z.writestr("y.npy", b.getvalue())
    if command == "train":
        args = ["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-test", "16"]
    else:
        assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0",
                     "--n-train", "64", "--n-test", "16", "-q", "--out", str(tmp_path / "r")]) == 0
        args = ["predict", str(tmp_path / "r")]
    code = main([*args, "-q", "--data", str(tmp_path / "dup.npz"), "--out", str(tmp_path / "o.npz")])
    assert code == 2 and "holds y.npy more than once" in capsys.readouterr().err
    assert not (tmp_path / "o.npz").exists()


@pytest.mark.parametrize("world", ["0", "-1"])
def test_a_world_size_below_one_is_refused(monkeypatch, world):
    from pdeinv.training.distributed import world_size_from_env

    monkeypatch.setenv("WORLD_SIZE", world)
    with pytest.raises(ValueError, match=rf"WORLD_SIZE='{world}' is not a number of processes"):
        world_size_from_env()


def test_a_noise_array_is_refused_in_one_short_line(tmp_path, capsys, rod):
    _, x, y = rod
    np.savez(tmp_path / "rows.npz", y=y, x=x, noise=np.full(len(y), 0.01))
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-test", "16",
                 "-q", "--data", str(tmp_path / "rows.npz"), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert f"noise of shape ({len(y)},) ({len(y)} values) is not allowed" in err and len(err) < 400, err


def test_a_dangling_link_given_as_data_is_called_a_missing_data_file(tmp_path, capsys, rod):
    (tmp_path / "dl.npz").symlink_to(tmp_path / "missing.npz")
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-train", "64",
                 "--n-test", "16", "-q", "--out", str(tmp_path / "r")]) == 0
    assert main(["predict", str(tmp_path / "r"), "-q", "--data", str(tmp_path / "dl.npz"),
                 "--out", str(tmp_path / "p.npz")]) == 2
    err = capsys.readouterr().err
    assert "data file" in err and "does not exist" in err and "another out" not in err, err


def test_nonlinear_data_in_other_units_is_refused_before_the_physics_runs(tmp_path, capsys):
    x, y = pdeinv.load_problem("allen_cahn_1d", n=16).sample(40, seed=0)
    np.savez(tmp_path / "big.npz", y=y * 1e100, x=x * 1e100)
    assert main(["train", "allen_cahn_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-test",
                 "16", "-q", "--data", str(tmp_path / "big.npz"), "--out", str(tmp_path / "r")]) == 2
    assert "physics is nonlinear, so its data must be in the problem's own units" in capsys.readouterr().err


@pytest.mark.parametrize("flag, said", [("--lr", "--lr -0.001 is not allowed"),
                                        ("--tau", "--tau -0.001 is not allowed")])
def test_a_negative_number_with_an_exponent_reaches_the_options_check(tmp_path, capsys, flag, said):
    assert main(["train", "heat_1d", "--set", "n=16", "--method", "hig", flag, "-1e-3", "--explain"]) == 2
    assert said in capsys.readouterr().err


@pytest.mark.parametrize("flag, value, said", [("--steps", "-inf", "invalid int value: '-inf'"),
                                               ("--seed", "-NaN", "invalid int value: '-NaN'"),
                                               ("--lr", "-Infinity", "--lr -inf is not allowed")])
def test_a_negative_infinity_or_nan_is_read_as_the_options_value(capsys, flag, value, said):
    """argparse takes ``-inf`` for an option ("expected one argument"); the value's own check names it."""
    try:
        code = main(["train", "heat_1d", "--set", "n=16", flag, value, "--explain"])
    except SystemExit as stop:  # argparse's own errors exit from the parser
        code = stop.code
    err = capsys.readouterr().err
    assert code == 2
    assert said in err and "expected one argument" not in err


def test_a_setting_that_underflows_to_zero_says_so(capsys):
    assert main(["train", "heat_1d", "--set", "kappa=1e-400", "--explain"]) == 2
    assert "kappa='1e-400' is out of range" in capsys.readouterr().err


def _module(tmp_path, name, body):
    head = "import dataclasses, sys\nimport numpy as np\nimport pdeinv\n\n"
    (tmp_path / f"{name}.py").write_text(head + body)
    return str(tmp_path / f"{name}.py")


def test_a_module_that_changes_numpys_error_handling_is_restored_and_trains(tmp_path, capsys):
    path = _module(tmp_path, "strict", "np.seterr(all='raise')\n\n"
                   "def make(**kw):\n    return pdeinv.load_problem('heat_1d', n=16, **kw)\n")
    before = np.geterr()
    assert main(["train", path, "--steps", "2", "--prior-fit", "0", "--n-train", "64", "--n-test", "16",
                 "-q", "--out", str(tmp_path / "r")]) == 0, capsys.readouterr().err
    assert np.geterr() == before and capsys.readouterr().err.count("np.seterr") == 1


def test_a_sampler_that_calls_sys_exit_is_named(tmp_path, capsys):
    path = _module(tmp_path, "quits", "def make(**kw):\n"
                   "    p = pdeinv.load_problem('heat_1d', n=16, **kw)\n"
                   "    return dataclasses.replace(p, sampler=lambda n, rng: sys.exit(4))\n")
    assert main(["train", path, "--steps", "2", "--prior-fit", "0", "--n-train", "64", "--n-test", "16",
                 "-q", "--out", str(tmp_path / "r")]) == 2
    assert "called sys.exit(4); expected the sampler to return the fields" in capsys.readouterr().err


def test_a_write_refused_by_permissions_is_not_called_a_full_disk(tmp_path, capsys, monkeypatch):
    import errno

    from pdeinv.cli.commands import train as command

    def refused(*a, **k):
        (tmp_path / "r" / "checkpoint.pt").write_bytes(b"")
        raise PermissionError(errno.EPERM, "Operation not permitted", str(tmp_path / "r" / "metrics.json"))

    monkeypatch.setattr(command, "_run", refused)
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-train", "64",
                 "--n-test", "16", "-q", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert "Operation not permitted" in err and "free space" not in err and "fix it and continue" in err


def test_a_setting_named_in_other_letter_case_is_the_one_it_spells():
    p = pdeinv.load_problem("heat_1d", n=16, scheme="BE", backend="Dense")
    assert p.settings["scheme"] == "be" and p.settings["backend"] == "dense"
    with pytest.raises(ValueError, match=r"scheme='B' is not allowed; expected one of 'be', 'cn'"):
        pdeinv.load_problem("heat_1d", n=16, scheme="B")


def test_a_file_noise_level_below_the_range_is_named_once(tmp_path, capsys, rod):
    _, x, y = rod
    np.savez(tmp_path / "tiny.npz", y=y, x=x, noise=1e-200)
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-test", "16",
                 "-q", "--data", str(tmp_path / "tiny.npz"), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "noise=1e-200 is out of range; expected 0 or a level between 1e-150 and 1e+150" in err
    assert err.count("tiny.npz") == 1, err


def test_sip_on_fresh_draws_with_few_training_rows_does_not_diverge(rod):
    """64 rows whiten 15 observations: a fresh row's variance along a whitened direction is up to 3.7×
    what those rows show, so a curvature measured on them stepped 2× too far (x_err 1.2, 5.0, … 25)."""
    p = rod[0]
    r = pdeinv.train(p, "sip", steps=10, n_train=64, fresh=True, eval_every=1, progress=False, **{
        k: v for k, v in KW.items() if k != "steps"})
    errs = [h["x_err"] for h in r.history if h.get("x_err") is not None]
    assert max(errs) < 1.0 and errs[-1] < 0.2 and not r.metrics["failed"], errs


def test_output_names_with_upper_case_endings_are_written_in_their_format(tmp_path, capsys, rod):
    _, x, y = rod
    np.savez(tmp_path / "d.npz", y=y, x=x)
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "2", "--prior-fit", "0", "--n-train", "64",
                 "--n-test", "16", "-q", "--out", str(tmp_path / "r")]) == 0
    assert main(["predict", str(tmp_path / "r"), "-q", "--data", str(tmp_path / "d.npz"),
                 "--out", str(tmp_path / "p.NPZ"), "--vtu", str(tmp_path / "f.VTU")]) == 0
    assert main(["show", str(tmp_path / "r"), "-q", "--png", str(tmp_path / "s.PNG")]) == 0
    assert np.load(tmp_path / "p.NPZ")["x"].shape == x.shape
    assert (tmp_path / "s.PNG").read_bytes()[:4] == b"\x89PNG" and (tmp_path / "f.VTU").stat().st_size > 0


@pytest.mark.parametrize("name, value", [("stop", "bogus"), ("prior", "bogus"), ("calibration", 5),
                                         ("device", "meta"), ("rule", "adam"), ("dtype", torch.float64)])
def test_any_setting_set_after_construction_is_refused_as_fit_starts(rod, name, value):
    t = pdeinv.Trainer(rod[0], "sip", n_train=64, **KW)
    setattr(t, name, value)
    with pytest.raises(ValueError, match=rf"trainer.{name} was set after construction"):
        t.fit()


def test_counts_and_equal_numbers_may_be_set_again_and_fit_twice(rod):
    t = pdeinv.Trainer(rod[0], "sip", n_train=64, **KW)
    t.steps, t.max_failures, t.seed = 3, 5, 1
    assert len(t.fit().history) >= 1 and len(t.fit().history) >= 1  # the built network is kept


def test_dataset_items_that_are_lists_of_numbers_are_observations(rod):
    p, _, y = rod

    class Rows(torch.utils.data.Dataset):
        def __len__(self):
            return len(y)

        def __getitem__(self, i):
            return list(y[i])

    t = pdeinv.Trainer(p, "sip", data=Rows(), **KW)
    assert np.allclose(t.held_out()[1], y[-16:])


def test_a_dataset_whose_items_fail_is_named_by_item(rod):
    p, _, y = rod

    class Short(torch.utils.data.Dataset):
        def __len__(self):
            return 100

        def __getitem__(self, i):
            if i >= len(y):
                raise IndexError(i)
            return torch.tensor(y[i])

    with pytest.raises(ValueError, match=r"item 80 of the Dataset \(len 100\) raised IndexError"):
        pdeinv.Trainer(p, "sip", data=Short(), **KW)


def test_masked_and_complex_inputs_are_refused(rod):
    p, _, y = rod
    with pytest.raises(ValueError, match=r"masked array with 15 masked values"):
        pdeinv.Trainer(p, "sip", data=np.ma.masked_array(y, mask=np.eye(80, 15, dtype=bool)), **KW)
    with pytest.raises(ValueError, match=r"expected a 2-D matrix of real numbers"):
        pdeinv.physics.Matrix(np.eye(4) * (1 + 1j))


@pytest.mark.parametrize("name", ["two\nlines", "x" * 201])
def test_problem_names_that_break_lines_or_file_names_are_refused(rod, name):
    import dataclasses

    with pytest.raises(ValueError, match=r"at most 200 printable characters"):
        dataclasses.replace(rod[0], name=name)


def test_a_numpy_string_name_is_kept_as_a_plain_string(rod):
    import dataclasses

    assert type(dataclasses.replace(rod[0], name=np.str_("heat_1d")).name) is str


@pytest.mark.parametrize("body", ["np.seterr(all='raise')\n    return rng.random((n, 15))",
                                  "raise GeneratorExit"])
def test_a_sampler_that_changes_numpy_or_raises_generator_exit(tmp_path, capsys, body):
    path = _module(tmp_path, "odd", f"def _s(n, rng):\n    {body}\n\n"
                   "def make(**kw):\n    p = pdeinv.load_problem('heat_1d', n=16, **kw)\n"
                   "    return dataclasses.replace(p, sampler=_s)\n")
    code = main(["train", path, "--steps", "2", "--prior-fit", "0", "--n-train", "64", "--n-test", "16", "-q",
                 "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert (code == 0) if "seterr" in body else (code == 2 and "GeneratorExit (the sampler" in err), err
    assert np.geterr()["under"] == "ignore"


def test_a_module_that_lowers_the_recursion_limit_is_restored(tmp_path, capsys):
    import sys

    limit = sys.getrecursionlimit()
    path = _module(tmp_path, "shallow", "import inspect\n\n"  # 30 frames above make's: the run needs more
                   "def make(**kw):\n    p = pdeinv.load_problem('heat_1d', n=16, **kw)\n"
                   "    sys.setrecursionlimit(len(inspect.stack()) + 30)\n    return p\n")
    assert main(["train", path, "--steps", "2", "--prior-fit", "0", "--n-train", "64", "--n-test", "16", "-q",
                 "--out", str(tmp_path / "r")]) == 0, capsys.readouterr().err
    assert sys.getrecursionlimit() == limit and "recursion limit" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["16_0", "１６"])
def test_numbers_python_reads_loosely_are_refused_as_settings(value):
    with pytest.raises(ValueError, match=r"is not a number; expected plain digits"):
        pdeinv.load_problem("heat_1d", n=value)


def test_optimizer_flags_must_be_booleans_and_lr_may_be_a_0d_tensor():
    with pytest.raises(ValueError, match=r"amsgrad='yes' is not True or False"):
        pdeinv.adam(1e-3, amsgrad="yes")
    assert pdeinv.adam(torch.tensor(1e-3)).keywords["lr"] == pytest.approx(1e-3)


def test_predict_names_a_low_precision_file_as_a_possible_cause(tmp_path, capsys):
    """float16 observations refused by predict name their storage (as train does), not only the physics."""
    run = tmp_path / "run"
    assert main(["train", "heat_1d", "--set", "n=16", "--steps", "3", "--prior-fit", "0", "--n-train", "32",
                 "--n-test", "16", "-q", "--out", str(run)]) == 0
    _, y = pdeinv.load_problem("heat_1d", n=16).sample(20, seed=3)
    np.savez(tmp_path / "f16.npz", y=y.astype(np.float16))
    np.savez(tmp_path / "f64.npz", y=y)
    capsys.readouterr()
    assert main(["predict", str(run), "-q", "--data", str(tmp_path / "f16.npz"), "--out",
                 str(tmp_path / "p16.npz")]) == 3
    err = capsys.readouterr().err
    assert "stored in lower precision than float64" in err and "save it in float64" in err
    assert err.count("\n") == 1
    assert main(["predict", str(run), "-q", "--data", str(tmp_path / "f64.npz"), "--out",
                 str(tmp_path / "p64.npz")]) == 0


def test_predict_takes_the_units_train_took_and_never_writes_nan(tmp_path, capsys):
    """A file at 1e300 trains (pdeinv.problem.units) and predicts with the same run (its amplitude check
    overflowed); a run trained in the problem's units, given that file with --accept-bad, refuses to write
    NaN predictions (exit 3, nothing written)."""
    _, y = pdeinv.load_problem("heat_1d", n=16).sample(120, seed=7)
    np.savez(tmp_path / "huge.npz", y=y * 1e300)
    np.savez(tmp_path / "plain.npz", y=y)
    small = ["--set", "n=16", "--steps", "3", "--prior-fit", "0", "--n-test", "32", "-q"]
    assert main(["train", "heat_1d", *small, "--data", str(tmp_path / "huge.npz"), "--out",
                 str(tmp_path / "h")]) == 0
    assert main(["predict", str(tmp_path / "h"), "-q", "--data", str(tmp_path / "huge.npz"), "--out",
                 str(tmp_path / "ph.npz")]) == 0
    xh = np.load(tmp_path / "ph.npz")["x"]
    assert np.isfinite(xh).all() and np.abs(xh).max() > 1e290
    assert main(["train", "heat_1d", *small, "--data", str(tmp_path / "plain.npz"), "--out",
                 str(tmp_path / "u")]) == 0
    capsys.readouterr()
    assert main(["predict", str(tmp_path / "u"), "-q", "--accept-bad", "--data", str(tmp_path / "huge.npz"),
                 "--out", str(tmp_path / "pu.npz")]) == 3
    assert "predictions of it are not finite" in capsys.readouterr().err
    assert not (tmp_path / "pu.npz").exists()
