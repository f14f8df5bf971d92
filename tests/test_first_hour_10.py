"""Bad and odd inputs of the ninth round (issue 48): `--explain` checks --out and --resume as the run
does, `write_fields` follows the output-path policy, a run's network, posterior and record are bound to each
other and to their problem, the no-field verdict does not depend on the data's units, Python refuses a
file of another physics as the CLI does, and a loop of links is named. Each case failed (a wrong exit 0, a
file replaced, an internal error, a verdict that changed with the units) on the code before."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.io import export
from pdeinv.io.runs import load_posterior, load_run, save_run
from pdeinv.posterior import predictive

SMALL = ["--set", "n=8", "--steps", "2", "--n-train", "32", "--n-test", "8", "--prior-fit", "0",
         "--threads", "1", "-q"]


def _one_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("\n") == 1, err
    return err


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two heat_1d n=8 runs with posteriors, κ 0.01 and 0.02."""
    tmp = tmp_path_factory.mktemp("runs")
    assert main(["train", "heat_1d", *SMALL, "--out", str(tmp / "base")]) == 0
    assert main(["train", "heat_1d", *SMALL, "--set", "kappa=0.02", "--out", str(tmp / "k2")]) == 0
    return tmp


@pytest.mark.parametrize("out, said", [
    ("docs", "holds notes.txt and is not a pdeinv run folder"),
    ("base", "metrics.json exists"),
    ("afile", "is a file"),
    ("afile/sub", "a file is in the way"),
])
def test_explain_checks_out_as_the_run_does(runs, tmp_path, monkeypatch, capsys, out, said):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "notes.txt").write_text("mine")
    (tmp_path / "afile").write_text("f")
    os.symlink(runs / "base", tmp_path / "base")
    assert main(["train", "heat_1d", "--set", "n=8", "--explain", "--out", out]) == 2
    assert said in _one_error(capsys)
    assert (tmp_path / "docs" / "notes.txt").read_text() == "mine"


def test_explain_checks_resume(runs, tmp_path, capsys):
    (tmp_path / "e").mkdir()
    assert main(["train", "heat_1d", "--set", "n=8", "--explain", "--resume",
                 "--out", str(tmp_path / "e")]) == 2
    assert "there is no checkpoint" in _one_error(capsys)
    assert main(["train", "heat_1d", "--set", "n=8", "--set", "kappa=0.02", "--explain", "--resume",
                 "--out", str(runs / "base")]) == 2
    assert "with other settings: kappa=0.01 (checkpoint) vs 0.02 (this run)" in _one_error(capsys)
    assert main(["train", "heat_1d", *SMALL, "--explain", "--resume", "--out", str(runs / "base")]) == 0
    assert main(["train", "heat_1d", *SMALL, "--explain", "--out", str(tmp_path / "new")]) == 0
    assert not (tmp_path / "new").exists()  # nothing created


def test_write_fields_follows_the_output_path_policy(runs, tmp_path):
    p = pdeinv.load_problem("heat_1d", n=8)
    x, _ = p.sample(2)
    before = (runs / "base" / "fields.vtu").read_bytes()
    with pytest.raises(ValueError, match="one of a run's own files"):
        export.write_fields(runs / "base" / "fields.vtu", p, x, x)
    assert (runs / "base" / "fields.vtu").read_bytes() == before
    (tmp_path / "keep.vtu").write_text("mine")
    with pytest.raises(ValueError, match=r"exists; pass overwrite=True"):
        export.write_fields(tmp_path / "keep.vtu", p, x, x)
    assert (tmp_path / "keep.vtu").read_text() == "mine"
    assert export.write_fields(tmp_path / "keep.vtu", p, x, x, overwrite=True).stat().st_size > 100
    with pytest.raises(TypeError, match="path=5 is int"):
        export.write_fields(5, p, x, x)
    with pytest.raises(ValueError, match="x_true has shape"):
        export.write_fields(tmp_path / "z" / "q.vtu", p, x[:, :3], x)
    assert not (tmp_path / "z").exists()  # the arrays are checked before any folder is made
    assert export.write_fields(tmp_path / "new" / "a" / "b.vtu", p, x, x).is_file()  # folders made


def test_a_loaded_network_is_saved_and_used_only_with_its_problem(runs, tmp_path):
    pb, mb = load_run(runs / "base")
    _, mk = load_run(runs / "k2")
    with pytest.raises(ValueError, match="kappa=0.02; the problem given has kappa=0.01"):
        save_run(tmp_path / "o", pb, model=mk)
    wave = pdeinv.load_problem("wave_1d", n=8)
    _, y = pb.sample(4, seed=5)
    post = load_posterior(runs / "base")
    with pytest.raises(ValueError, match="trained on problem 'heat_1d', not on 'wave_1d'"):
        predictive(mb, post, y, problem=wave)
    with pytest.raises(ValueError, match="trained on problem 'heat_1d', not on 'wave_1d'"):
        export.predict(mb, y, problem=wave)
    assert predictive(mb, post, y, problem=pb)["x"].shape == (4, pb.N)
    assert not (tmp_path / "o").exists()


def test_a_posterior_is_used_only_with_its_network(runs, tmp_path):
    pb, mb = load_run(runs / "base")
    _, mk = load_run(runs / "k2")
    _, y = pb.sample(4, seed=5)
    with pytest.raises(ValueError, match="the posterior was fitted for another network"):
        predictive(mk, load_posterior(runs / "base"), y)
    with pytest.raises(ValueError, match="the posterior was fitted for another network"):
        save_run(tmp_path / "o", pb, model=mb, posterior=load_posterior(runs / "k2"))
    ok = save_run(tmp_path / "ok", pb, model=mb, posterior=load_posterior(runs / "base"))
    assert load_posterior(ok, pb) is not None


@pytest.mark.parametrize("call, exc, match", [
    (lambda run, p, m, y: load_posterior(run, problem="heat_1d"), TypeError, "problem='heat_1d' is str"),
    (lambda run, p, m, y: predictive(m, load_posterior(run), y, level="0.9"), TypeError,
     "level='0.9' is str"),
    (lambda run, p, m, y: predictive(m, load_posterior(run), y, samples=2, seed=2**80), ValueError,
     "expected an integer from 0 to 4294967295"),
])
def test_posterior_arguments_named(runs, call, exc, match):
    p, m = load_run(runs / "base")
    _, y = p.sample(2, seed=1)
    with pytest.raises(exc, match=match):
        call(runs / "base", p, m, y)


def test_an_edited_run_record_is_refused(runs, tmp_path, capsys):
    import shutil

    run = tmp_path / "edited"
    shutil.copytree(runs / "base", run)
    record = json.loads((run / "run.json").read_text())
    record["overrides"]["kappa"] = "0.05"
    (run / "run.json").write_text(json.dumps(record))
    p = pdeinv.load_problem("heat_1d", n=8)
    _, y = p.sample(3, seed=2)
    np.savez(tmp_path / "obs.npz", y=y)
    assert main(["predict", str(run), "--data", str(tmp_path / "obs.npz"),
                 "--out", str(tmp_path / "p.npz")]) == 2
    assert "run.json was edited after the run" in _one_error(capsys)
    assert not (tmp_path / "p.npz").exists()


@pytest.mark.parametrize("units", [1.0, 1e3, 1e5, 1e13])
def test_the_no_field_verdict_does_not_depend_on_the_units(tmp_path, capsys, units):
    p = pdeinv.load_problem("heat_1d", n=8)
    _, y = p.sample(300, seed=2)
    np.savez(tmp_path / "y.npz", y=y * units)
    code = main(["train", "heat_1d", "--set", "n=8", "--steps", "2", "--n-test", "8", "--prior-fit", "0",
                 "--threads", "1", "-q", "--data", str(tmp_path / "y.npz"), "--out", str(tmp_path / "r")])
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert metrics["failed"] is None and metrics["amplitude"] < 10


def test_data_of_another_physics_is_still_refused_without_x(tmp_path, capsys):
    w = pdeinv.load_problem("wave_1d", n=8)
    _, y = w.sample(300, seed=2)
    np.savez(tmp_path / "wave.npz", y=y)
    code = main(["train", "heat_1d", "--set", "n=8", "--steps", "2", "--n-test", "8", "--prior-fit", "0",
                 "--threads", "1", "-q", "--data", str(tmp_path / "wave.npz"), "--out", str(tmp_path / "r")])
    assert code == 3
    assert "the prior's rms amplitude, per unit of the observations'" in capsys.readouterr().err


def test_python_refuses_a_file_of_other_settings_as_the_cli_does():
    p = pdeinv.load_problem("heat_1d", n=8)
    x, y = pdeinv.load_problem("heat_1d", n=8, kappa=0.05).sample(300, seed=3)
    with pytest.raises(ValueError, match="come from another physics or other settings.*accept_bad=True"):
        pdeinv.Trainer(p, "sip", steps=2, n_test=8, prior=None, data=y, data_x=x)
    with pytest.warns(RuntimeWarning, match="differ from this problem's P x"):
        t = pdeinv.Trainer(p, "sip", steps=2, n_test=8, prior=None, calibration=None, data=y, data_x=x,
                           accept_bad=True)
    assert t.fit().metrics["x_err"] > 0


def test_a_loop_of_links_as_out_is_named(tmp_path, capsys):
    os.symlink(tmp_path / "b", tmp_path / "a")
    os.symlink(tmp_path / "a", tmp_path / "b")
    assert main(["train", "heat_1d", *SMALL, "--out", str(tmp_path / "a")]) == 2
    assert "leads into a loop of symbolic links" in _one_error(capsys)


def test_an_overflowing_step_says_its_own_words_only(tmp_path, capsys):
    assert main(["train", "heat_1d", *SMALL, "--eta", "1e308", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert "encountered" not in err and "numerical failure" in err


def test_a_sample_of_the_users_that_returns_nan_is_named(tmp_path, capsys):
    module = tmp_path / "nan_sample.py"
    module.write_text("import numpy as np\nfrom pdeinv import load_problem\n\n\ndef make(**kw):\n"
                      "    p = load_problem('heat_1d', n=8)\n    orig = p.sample\n\n"
                      "    def sample(b, seed=0):\n        x, y = orig(b, seed=seed)\n"
                      "        x = x.copy()\n        x[0, 0] = np.nan\n        return x, y\n\n"
                      "    p.sample = sample\n    return p\n")
    assert main(["train", str(module), *SMALL[2:], "--out", str(tmp_path / "r")]) == 2
    assert "its sample(32) returned x with NaN or Inf" in _one_error(capsys)


def test_more_sensors_than_unknowns_is_said():
    with pytest.raises(ValueError, match="100000 sensors on a mesh of 9 unknowns see at most 9"):
        pdeinv.load_problem("heat_sensors_2d", n=4, sensors=100000)


def test_a_deleted_model_digest_is_an_edit(runs, tmp_path, capsys):
    import shutil

    run = tmp_path / "nodigest"
    shutil.copytree(runs / "base", run)
    record = json.loads((run / "run.json").read_text())
    del record["model_sha256"]
    (run / "run.json").write_text(json.dumps(record))
    with pytest.raises(ValueError, match="run.json was edited after the run"):
        load_run(run)


def test_explain_checks_the_checkpoint_as_resume_does(tmp_path, capsys):
    run = tmp_path / "r"
    assert main(["train", "heat_1d", *SMALL, "--checkpoint-every", "1", "--out", str(run)]) == 0
    base = ["train", "heat_1d", "--set", "n=8", "--n-train", "32", "--n-test", "8", "--prior-fit", "0",
            "--threads", "1", "-q", "--resume", "--explain", "--out", str(run)]
    for extra, said in ((["--steps", "1"], "has 2 steps done; steps=1 is below that"),
                        (["--seed", "9"], "seed=0 (checkpoint) vs 9 (this run) (--seed)"),
                        (["--method", "adam"], "written with rule 'sip'; this run has 'adam'")):
        assert main([*base, *extra]) == 2
        assert said in _one_error(capsys)
    assert main([*base, "--steps", "3"]) == 0


def test_classical_reads_the_noise_level_off_the_files_x(tmp_path, capsys):
    p = pdeinv.load_problem("heat_1d", n=8)  # 7 observations: all signal, no spectral tail to read noise off
    x, y = p.sample(80, seed=1)
    np.savez(tmp_path / "exact.npz", y=y, x=x)
    xn, yn = pdeinv.load_problem("heat_1d", n=8, noise=0.01).sample(80, seed=1)
    np.savez(tmp_path / "noisy.npz", y=yn, x=xn)
    for name, lo, hi in (("exact", 0.0, 0.0), ("noisy", 0.008, 0.012)):
        assert main(["classical", "heat_1d", "--set", "n=8", "--threads", "1", "--data",
                     str(tmp_path / f"{name}.npz")]) == 0
        noise = json.loads(capsys.readouterr().out.split("heat_1d noise: ")[1].splitlines()[0])
        assert lo <= noise["level"] <= hi, noise
    np.savez(tmp_path / "huge.npz", y=y, x=x, noise=1e308)
    assert main(["classical", "heat_1d", "--set", "n=8", "--data", str(tmp_path / "huge.npz")]) == 2
    assert "is out of range" in _one_error(capsys)


def test_api_arguments_of_round_ten(tmp_path):
    from pdeinv.nets.refine import PriorFit
    from pdeinv.posterior import CalibrationStage

    with pytest.raises(ValueError, match=r"PriorFit\(min_gain=-0.1\) is not allowed"):
        PriorFit(min_gain=-0.1)
    with pytest.raises(TypeError, match=r"CalibrationStage\(name\)=None is NoneType"):
        CalibrationStage(name=None)
    with pytest.raises(ValueError, match="holds no run.json: not a pdeinv run"):
        load_posterior(tmp_path)
    with pytest.raises(ValueError, match="problem module '.*nope.py' does not exist"):  # also FileNotFound
        pdeinv.load_problem(str(tmp_path / "nope.py"))
    p = pdeinv.load_problem("heat_1d", n=8)
    x, _ = p.sample(2)
    one_line = r"^bars=\{'std': array\(\[\[1\., 1\., 1\.\], \[1\., 1\., 1\.\]\]\)\} "
    with pytest.raises(TypeError, match=one_line):
        export.write_fields(tmp_path / "m.vtu", p, x, x, bars={"std": np.ones((2, 3))})


def test_a_users_module_leaves_no_bytecode_in_its_folder(tmp_path, monkeypatch, capsys):
    (tmp_path / "helper_mod.py").write_text("X = 1\n")
    (tmp_path / "lam.py").write_text('"""lam"""\nimport helper_mod\nfrom pdeinv import load_problem\n\n\n'
                                     "def make(**kw):\n    return load_problem('heat_1d', n=8)\n")
    assert main(["train", str(tmp_path / "lam.py"), *SMALL[2:], "--out", str(tmp_path / "r")]) == 0
    monkeypatch.setenv("PDEINV_PROBLEMS", str(tmp_path))
    assert main(["problems"]) == 0
    assert "lam: lam" in capsys.readouterr().out  # its sibling imported in the listing's child too
    assert not (tmp_path / "__pycache__").exists()


def test_predict_refuses_observations_of_another_physics_without_x(runs, tmp_path, capsys):
    w = pdeinv.load_problem("wave_1d", n=8)
    _, y = w.sample(80, seed=4)
    np.savez(tmp_path / "wave.npz", y=y)
    out = tmp_path / "p.npz"
    assert main(["predict", str(runs / "base"), "--data", str(tmp_path / "wave.npz"), "--out", str(out)]) == 3
    assert "is no field of this run's prior" in _one_error(capsys)
    assert not out.exists()
    _, y = pdeinv.load_problem("heat_1d", n=8).sample(80, seed=4)
    np.savez(tmp_path / "heat.npz", y=y)
    assert main(["predict", str(runs / "base"), "--data", str(tmp_path / "heat.npz"), "--out", str(out)]) == 0
