"""Bad and odd inputs of the thirteenth round (issue 48): a flag given twice, a sweep into its own earlier
results, `bench` on nonlinear physics, another run's checkpoint under the API, a network `load_run` could
not rebuild, a user's thread or sampler that fails, an ASCII or closed stdout, a rank alone in its group,
SIGHUP, MPLBACKEND, a `make()` that changes folder, paths that name a folder or exceed PATH_MAX; and what
round twelve left: `classical --accept-bad` on y 1e200 times x (the MMSE's factors and the norms of fields
at 1e-200 underflowed: "X contains NaN" on finite data). Each failed on the code before."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.training import references


def _one_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and "Warning" not in err and err.count("\n") == 1, err
    return err


SMALL_RUN = ["--steps", "2", "--n-train", "32", "--n-test", "8", "--prior-fit", "0", "--threads", "1", "-q"]


def test_classical_accept_bad_on_mismatched_units_reports_the_mismatch(tmp_path, capsys):
    p = pdeinv.load_problem("heat_1d", n=16)
    x, y = p.sample(200, 0)
    np.savez(tmp_path / "units.npz", x=x, y=y * 1e200)
    assert main(["classical", "heat_1d", "--set", "n=16", "--data", str(tmp_path / "units.npz"),
                 "--accept-bad"]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "Warning" not in err and "NaN" not in out + err, err
    assert "warning: the file's y differ from this problem's P x by 1" in err
    # the estimates are in y's units, 1e200 times the file's x: their error says so
    rows = {line.split(": ", 1)[0].split()[-1]: line.split(": ", 1)[1] for line in out.splitlines()}
    assert 1e199 < json.loads(rows["mmse_file_x"])["x_err"] < 1e201


# (units, noise, tolerance, rule): a² σ² must be a float64 for the noisy case; the noise-free solve at
# σ = 1e-8 s_max amplifies rounding by up to 1e8, so its scaled factors agree to ~1e-8
@pytest.mark.parametrize("a, noise, tol, rule", [
    *[(a, 0.01, (1e-9, 1e-12), "noise") for a in (1e-150, 1.0, 1e150)],
    *[(a, 0.0, (1e-6, 1e-8), "tiny σ = 1e-8·s_max") for a in (1e-200, 1e200)],
])
def test_the_linear_mmse_is_the_same_in_any_units(a, noise, tol, rule):
    p = pdeinv.load_problem("heat_1d", n=16, noise=noise)
    x, y = p.sample(300, 0)
    ref, info = references.mmse(p, x[:200])
    est, scaled = references.mmse(p, a * x[:200], a * a * info["sigma2"] if noise else None)
    np.testing.assert_allclose(est(a * y[200:]) / a, ref(y[200:]), rtol=tol[0], atol=tol[1])
    assert scaled["sigma2_rule"] == info["sigma2_rule"] == rule


@pytest.mark.parametrize("a", [1e-300, 1e300])
def test_the_l2_norm_of_fields_whose_squares_leave_float64(a):
    p = pdeinv.load_problem("heat_2d", n=8)
    x, _ = p.sample(4, 0)
    np.testing.assert_allclose(p.disc.norm(a * x) / a, p.disc.norm(x), rtol=1e-14)
    # an estimate 1e200 times the field: an error of 1e200, not NaN
    np.testing.assert_allclose(p.relative_error(1e100 * x, 1e-100 * x), 1e200, rtol=1e-12)
    assert np.array_equal(p.disc.norm(np.zeros((2, p.N))), [0.0, 0.0])


def test_a_prior_fit_says_how_long_it_will_take_after_its_first_steps(tmp_path, capsys):
    """The first held-out check comes after a pass over the draws (minutes at 64²): the pace comes
    after :data:`pdeinv.nets.refine.PACE_STEPS`."""
    from pdeinv.nets.refine import PACE_STEPS

    args = ["train", "heat_2d", "--set", "n=8", "--set", "noise=0.01", "--steps", "2", "--n-train", "64",
            "--n-test", "16", "--prior-fit", str(3 * PACE_STEPS), "--threads", "1"]
    assert main([*args, "--out", str(tmp_path / "r")]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "prior fit step" in ln]
    assert f"prior fit step {PACE_STEPS}/{3 * PACE_STEPS}: " in lines[1] and "left at this pace" in lines[1]
    assert main([*args, "-q", "--out", str(tmp_path / "q")]) == 0
    assert "prior fit" not in capsys.readouterr().err


def test_hig_names_the_route_it_falls_back_to_once_per_run():
    """The warning came once per step wherever a step's warnings filters were reset (the CLI showed
    it twice in a two-step run)."""
    import warnings

    import torch

    p = pdeinv.load_problem("heat_1d", n=16)
    torch.manual_seed(0)
    model = pdeinv.nets.mlp((64, 64))(p)
    rule = pdeinv.HIG(max_jacobian_gb=1e-4)  # the Gram route does not fit: a cheaper one is taken
    state = rule.init(p, model)
    _, y = p.sample(8, 0)
    y = torch.as_tensor(y, dtype=torch.float32)
    seen = []
    for _ in range(2):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rule.update(state, model, y)
        seen += [str(w.message) for w in caught if "taking the" in str(w.message)]
    assert len(seen) == 1 and "max_jacobian_gb=0.0001" in seen[0]


def test_a_thread_of_a_problem_module_that_raises_is_one_line(tmp_path, capsys):
    module = tmp_path / "threads.py"
    module.write_text("import threading\n"
                      "import pdeinv\n\n"
                      "def _bad():\n    raise RuntimeError('thread boom')\n\n"
                      "def make(**kw):\n"
                      "    t = threading.Thread(target=_bad, name='worker')\n    t.start()\n    t.join()\n"
                      "    return pdeinv.load_problem('heat_1d', n=8)\n")
    assert main(["train", str(module), *SMALL_RUN, "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    assert f"warning: thread 'worker' ended at {module}, line 5, in _bad: RuntimeError: thread boom" in err


@pytest.mark.parametrize("flag, argv", [
    ("--steps", ["train", "heat_1d", "--steps", "2", "--steps", "3", "--explain"]),
    ("--method", ["train", "heat_1d", "--method", "sip", "--method=adam", "--explain"]),
    ("--seed", ["train", "heat_1d", "--seed", "1", "--seed", "2", "--explain"]),
    ("--data", ["classical", "heat_1d", "--data", "a.npz", "--data", "b.npz"]),
    ("--level", ["predict", "run", "--data", "a.npz", "--out", "p.npz", "--level", "0.9", "--level", "0.5"]),
])
def test_a_flag_given_twice_is_refused(flag, argv, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    assert f"{flag} is given twice" in _one_error(capsys) and not list(tmp_path.iterdir())


def test_a_flag_given_twice_with_one_value_is_that_value(capsys):
    assert main(["train", "heat_1d", "--seed", "1", "--seed", "01", "--steps", "2", "--explain"]) == 0
    assert "2 steps" in capsys.readouterr().out


def test_a_second_stress_into_the_same_folder_needs_overwrite(tmp_path, capsys):
    args = ["stress", "heat_1d", "--quick", "--set", "n=8", "--out", str(tmp_path / "s"), "-q"]
    assert main(args) == 0
    before = (tmp_path / "s" / "stress.json").read_bytes()
    capsys.readouterr()
    assert main(args) == 2
    assert "holds this command's earlier results (stress.json); pass --overwrite" in _one_error(capsys)
    assert (tmp_path / "s" / "stress.json").read_bytes() == before
    assert main([*args, "--overwrite"]) == 0


def test_bench_runs_on_nonlinear_physics(tmp_path, capsys):
    """It called the adjoint of a linear operator (AttributeError), then the linear references."""
    args = ["bench", "sine_gordon_1d", "--quick", "--set", "n=8", "--out", str(tmp_path / "b"), "-q"]
    assert main(args) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "error" not in err, err
    assert "reference: none (nonlinear physics)" in out
    record = json.loads((tmp_path / "b" / "bench.json").read_text())
    assert record["reference"] is None and record["ratios"]["adjoint_vs_forward"] > 0
    assert any("nonlinear physics" in note for note in record["notes"])
    assert record["methods"]["sip_cli_default"]["x_err"] < 1


def test_the_api_does_not_replace_another_runs_checkpoint(tmp_path):
    p = pdeinv.load_problem("heat_1d", n=16)
    kw = dict(steps=2, n_train=64, n_test=16, prior=None, calibration=None)
    path = tmp_path / "run" / "checkpoint.pt"
    pdeinv.Trainer(p, "sip", checkpoint=pdeinv.Checkpoint(path, 1), **kw).fit()
    before = path.read_bytes()
    with pytest.raises(ValueError, match=r"holds another run's checkpoint: resume=True continues it, "
                                         r"Checkpoint\(.*, overwrite=True\) replaces it"):
        pdeinv.Trainer(p, "adam", checkpoint=pdeinv.Checkpoint(path, 1), **kw)
    assert path.read_bytes() == before
    pdeinv.Trainer(p, "adam", checkpoint=pdeinv.Checkpoint(path, 1, overwrite=True), **kw).fit()
    assert path.read_bytes() != before
    with pytest.raises(TypeError, match=r"Checkpoint\(overwrite\)='yes' is str"):
        pdeinv.Checkpoint(path, 1, overwrite="yes")


def test_demo_of_a_field_carried_out_of_the_domain_has_a_finite_dot_product_test(capsys):
    assert main(["demo", "advection_diffusion_2d", "--batch", "2", "--set", "n=4", "--set", "speed=1e2"]) == 0
    out, err = capsys.readouterr()
    assert "Warning" not in err, err
    dot = float(next(line for line in out.splitlines() if "dot_product_test" in line).split(":")[1])
    assert 0 <= dot < 1e-12
    # carried all the way out, nothing is left to observe: one line, before any 0/0
    assert main(["demo", "advection_diffusion_2d", "--batch", "2", "--set", "n=4", "--set", "speed=1e6"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Warning" not in err and "the physics leaves nothing to observe" in err


@pytest.mark.parametrize("name, says", [("pred.npz/", "ends in '/', a folder; expected a file name"),
                                        (".npz", "is an ending alone; expected a name before it")])
def test_an_output_file_named_as_a_folder_or_an_ending_is_refused(name, says, tmp_path):
    from pdeinv.util.outpaths import OutputPathError, output_file

    with pytest.raises(OutputPathError, match=says):
        output_file(str(tmp_path) + "/" + name, "--out", suffixes=(".npz",))
    assert not list(tmp_path.iterdir())


def _cli(shell: str, **env):
    import os
    import subprocess
    import sys

    return subprocess.run(["sh", "-c", shell.replace("PDEINV", f"{sys.executable} -m pdeinv.cli")],
                          capture_output=True, text=True, env={**os.environ, **env}, timeout=120)


def test_problems_on_an_ascii_terminal_escapes_what_it_cannot_print():
    done = _cli("PDEINV problems", PYTHONIOENCODING="ascii")
    assert done.returncode == 0, done.stderr
    assert "Advection\\u2013diffusion" in done.stdout and not done.stderr


def test_a_closed_stdout_is_an_error_not_a_silent_exit_0():
    done = _cli("PDEINV problems >&-")
    assert done.returncode == 1
    assert done.stderr == "pdeinv problems: error: cannot write: standard output is closed\n"


def test_hig_with_an_eta_of_1e308_fails_as_a_run_not_as_an_internal_error(tmp_path, capsys):
    code = main(["train", "heat_1d", "--set", "n=16", *SMALL_RUN, "--method", "hig", "--eta", "1e308",
                 "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code != 0 and "internal error" not in err and "OverflowError" not in err, err


def test_a_sampler_that_takes_no_rng_is_named(tmp_path, capsys):
    module = tmp_path / "lam.py"
    module.write_text("import dataclasses\nimport pdeinv\n\n\ndef make(**kw):\n"
                      "    p = pdeinv.load_problem('heat_1d', n=8)\n"
                      "    return dataclasses.replace(p, sampler=lambda n: None)\n")
    assert main(["train", str(module), *SMALL_RUN, "--out", str(tmp_path / "r")]) == 2
    err = _one_error(capsys)
    assert f"its sampler make.<locals>.<lambda> ({module}, line 7) cannot be called as sampler(n, rng)" in err
    assert "internal error" not in err


def test_save_run_refuses_a_network_load_run_could_not_rebuild(tmp_path):
    import torch

    p = pdeinv.load_problem("heat_1d", n=16)
    with pytest.raises(ValueError, match=r"save_run: model \(Linear\) is not the network run.json would "
                                         r"record \(\{\"kind\": \"default\"\}: model.pt has no 'active'"):
        pdeinv.save_run(tmp_path / "r", p, model=torch.nn.Linear(15, 15))
    assert not (tmp_path / "r").exists()
    pdeinv.save_run(tmp_path / "d", p, model=p.model())  # the default network, built by hand: reloads
    assert type(pdeinv.load_run(tmp_path / "d")[1]) is type(p.model())


def test_a_rank_alone_in_its_group_is_told_to_launch_every_rank(tmp_path, monkeypatch, capsys):
    import socket

    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    for key, value in dict(WORLD_SIZE="2", RANK="0", LOCAL_RANK="0", PDEINV_DDP_TIMEOUT="2",
                           MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port)).items():
        monkeypatch.setenv(key, value)
    assert main(["train", "heat_1d", "--set", "n=16", *SMALL_RUN, "--out", str(tmp_path / "r")]) == 2
    err = _one_error(capsys)
    assert "did not form a group within PDEINV_DDP_TIMEOUT=2 s" in err
    assert "torchrun --nproc-per-node 2" in err


def test_a_warning_of_any_command_is_one_line(monkeypatch, capsys):
    """Python's form adds the file and the echoed source line (stress showed them)."""
    import warnings

    import pdeinv.cli as cli

    def noisy(args):
        warnings.warn("the predictions carry 1e11× the prior's energy", RuntimeWarning)
        return 0

    real = cli.build_parser

    def built():
        parser = real()
        parser.commands["problems"].set_defaults(func=noisy)
        return parser

    monkeypatch.setattr(cli, "build_parser", built)
    assert main(["problems"]) == 0
    says = "pdeinv problems: warning: the predictions carry 1e11× the prior's energy\n"
    assert capsys.readouterr().err == says


def test_an_unknown_mplbackend_is_refused_before_any_work(tmp_path):
    done = _cli(f"cd {tmp_path} && PDEINV train heat_1d --set n=8 --steps 2 --prior-fit 0 -q --out r",
                MPLBACKEND="bogus")
    assert done.returncode == 2 and not list(tmp_path.iterdir())
    assert done.stderr == ("pdeinv train: error: MPLBACKEND='bogus' is not a backend of matplotlib's; "
                           "unset it, or set it to one such as 'Agg'\n")


def test_settings_resolve_names_an_argument_that_is_no_dict():
    from pdeinv.problem import settings

    with pytest.raises(TypeError, match=r"settings.resolve\(spec=None\) is NoneType; expected a dict"):
        settings.resolve(None, {}, "x")
    with pytest.raises(TypeError, match=r"settings.resolve\(overrides=None\) is NoneType; expected a dict"):
        settings.resolve({"n": (16, settings.positive_int)}, None, "x")


def test_resuming_with_another_network_names_the_network_not_its_dtype(tmp_path, capsys):
    args = ["train", "heat_1d", "--set", "n=16", "--method", "gd", "--prior-fit", "0", "--n-train", "64",
            "--n-test", "16", "--checkpoint-every", "1", "--threads", "1", "-q", "--out", str(tmp_path / "r")]
    assert main([*args, "--steps", "2"]) == 0
    capsys.readouterr()
    assert main([*args, "--steps", "4", "--resume", "--hidden", "8,8"]) == 2
    err = _one_error(capsys)
    assert "holds a Refined network; this run's is a MLP" in err and "dtype" not in err


def test_an_output_path_longer_than_the_system_takes_is_exit_2_in_one_short_line(tmp_path, capsys):
    long = "/".join(["c" * 200] * 25)  # every name within NAME_MAX, the path beyond PATH_MAX
    assert main(["train", "heat_1d", "--set", "n=8", *SMALL_RUN, "--out", str(tmp_path / long)]) == 2
    err = _one_error(capsys)
    assert "bytes long as a full path; expected fewer than 4096" in err and len(err) < 300


def test_a_module_whose_make_changes_folder_still_gives_a_whole_run(tmp_path, monkeypatch, capsys):
    (tmp_path / "problems").mkdir()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "problems" / "wander.py").write_text(
        "import os\nimport pdeinv\n\n\ndef make(**kw):\n"
        f"    os.chdir({str(tmp_path / 'elsewhere')!r})\n    return pdeinv.load_problem('heat_1d', n=8)\n")
    monkeypatch.chdir(tmp_path)
    assert main(["train", "problems/wander.py", *SMALL_RUN, "--out", "run"]) == 0
    assert (tmp_path / "run" / "run.json").is_file() and (tmp_path / "run" / "model.pt").is_file()
    monkeypatch.chdir(tmp_path)
    assert pdeinv.load_run(tmp_path / "run")[0].N == 7


@pytest.mark.parametrize("name, value, says", [("steps", -5, r"steps=-5 is not allowed"),
                                               ("n_test", "abc", r"n_test='abc'"),
                                               ("batch_size", 10_000, r"batch_size=10000 is larger")])
def test_a_trainer_setting_changed_after_construction_is_checked_by_fit(name, value, says):
    p = pdeinv.load_problem("heat_1d", n=16)
    trainer = pdeinv.Trainer(p, "sip", steps=2, n_train=64, n_test=16, prior=None, calibration=None)
    setattr(trainer, name, value)
    with pytest.raises((ValueError, TypeError), match=says):
        trainer.fit()
