"""Bad and odd inputs of the fifteenth round (issue 48): an operator whose observations float32 cannot
hold, a module edited after its run, a problem name longer than any file name, settings that leave
nothing to recover. Each ended with exit 0, an internal error or a message naming the wrong cause on the
code before."""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.io import runs

TINY = ["--steps", "2", "--prior-fit", "0", "--n-train", "64", "--n-test", "16", "-q"]


def test_an_operator_scaled_by_1e300_is_refused_naming_the_operator():
    p = pdeinv.load_problem("heat_1d", n=16)
    huge = dataclasses.replace(p, operator=pdeinv.physics.Matrix(np.eye(p.N) * 1e300), inverse_simulator=None)
    with pytest.raises(ValueError, match=r"observations up to .*e\+(299|300) .*rescale its operator"):
        huge.sample(4)


def test_cli_train_of_a_module_with_a_huge_operator_exits_2(tmp_path, capsys):
    (tmp_path / "huge.py").write_text(
        "import dataclasses\nimport numpy as np\nimport pdeinv\n\n"
        "def make(**kw):\n    p = pdeinv.load_problem('heat_1d', n=16, **kw)\n"
        "    return dataclasses.replace(p, operator=pdeinv.physics.Matrix(np.eye(p.N) * 1e300), "
        "inverse_simulator=None)\n")
    assert main(["train", str(tmp_path / "huge.py"), *TINY, "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "rescale its operator" in err and "internal error" not in err


def test_settings_that_leave_no_signal_are_named_not_the_operator():
    with pytest.raises(ValueError, match=r"the physics leaves nothing to observe: settings such as"):
        pdeinv.load_problem("heat_2d", n=8, kappa=2).sample(4)


def test_settings_that_leave_one_direction_warn_that_the_prior_decides(recwarn):
    p = pdeinv.load_problem("heat_1d", n=16, kappa=2)
    pdeinv.train(p, "sip", steps=2, n_train=64, n_test=16, prior=None, calibration=None)
    said = [str(w.message) for w in recwarn if "directions of x" in str(w.message)]
    assert said and "the estimate is mostly the prior's" in said[0]
    quiet = pdeinv.load_problem("heat_1d", n=16)  # the default settings: nothing said
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        pdeinv.train(quiet, "sip", steps=2, n_train=64, n_test=16, prior=None, calibration=None)
    assert not any("directions of x" in str(w.message) for w in record)


@pytest.fixture()
def edited(tmp_path):
    module = tmp_path / "rod.py"
    module.write_text("import pdeinv\n\ndef make(**kw):\n    return pdeinv.load_problem('heat_1d', n=16, "
                      "kappa=0.01, **kw)\n")
    assert main(["train", str(module), *TINY, "--out", str(tmp_path / "r")]) == 0
    x, y = pdeinv.load_problem(str(module)).sample(8, seed=1)
    np.savez(tmp_path / "obs.npz", y=y, x=x)
    return module, tmp_path


def test_predict_after_the_module_is_edited_names_the_problem_not_model_pt(edited, capsys):
    module, tmp = edited
    assert main(["predict", str(tmp / "r"), "--data", str(tmp / "obs.npz"), "--out", str(tmp / "a.npz")]) == 0
    module.write_text(module.read_text().replace("kappa=0.01", "kappa=0.03"))
    capsys.readouterr()
    assert main(["predict", str(tmp / "r"), "--data", str(tmp / "obs.npz"), "--out", str(tmp / "b.npz")]) == 2
    err = capsys.readouterr().err
    assert "is not the one the run was trained on" in err and "model.pt" not in err
    assert not (tmp / "b.npz").exists()


def test_a_record_without_a_fingerprint_still_loads(edited):
    _, tmp = edited
    record = json.loads((tmp / "r" / "run.json").read_text())
    assert record["fingerprint"]["unknowns"] == 15
    del record["fingerprint"]  # a run of a pdeinv before fingerprints: its digest without one
    record["record_sha256"] = runs._record_digest(record)
    (tmp / "r" / "run.json").write_text(json.dumps(record))
    problem, _ = runs.load_run(tmp / "r")
    assert problem.N == 15


def test_an_edited_fingerprint_is_refused_as_an_edit(edited):
    _, tmp = edited
    record = json.loads((tmp / "r" / "run.json").read_text())
    record["fingerprint"]["x"] = "many"
    (tmp / "r" / "run.json").write_text(json.dumps(record))
    with pytest.raises(ValueError, match=r"run.json's 'fingerprint' is"):
        runs.load_run(tmp / "r")


@pytest.mark.parametrize("size", [300, 5000])
def test_a_problem_name_longer_than_a_file_name_is_one_line(tmp_path, capsys, size):
    assert main(["train", "a" * size, "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert f"({size} characters); a problem name has at most 200" in err and "cannot write" not in err
    assert len(err) < 400


def test_a_module_path_longer_than_a_file_name_is_one_line(tmp_path, capsys):
    assert main(["train", str(tmp_path / ("a" * 300 + ".py")), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "cannot be looked up (File name too long)" in err and len(err) < 400


@pytest.mark.parametrize("flag, text", [("--steps", "２"), ("--steps", "1_000"), ("--steps", " 2"),
                                        ("--seed", "２"), ("--lr", "1e-3 ")])
def test_numeric_flags_take_plain_ascii_numbers_only(tmp_path, capsys, flag, text):
    rest = ["--prior-fit", "0", "--n-train", "64", "--n-test", "16", "-q", "--out", str(tmp_path / "r")]
    args = ["train", "heat_1d", *rest, *([] if flag == "--steps" else ["--steps", "2"]), flag, text]
    with pytest.raises(SystemExit) as exit_:  # argparse's usage error
        main(args)
    assert exit_.value.code == 2
    assert f"argument {flag}: {text!r} is not a plain number" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("item", ["kappa= 0.02", "kappa =0.02", "kappa=0.02 "])
def test_a_setting_with_spaces_around_is_refused(capsys, item):
    assert main(["train", "heat_1d", "--set", item, "--explain"]) == 2
    assert "has spaces around its key or value" in capsys.readouterr().err
