"""Numbers and files are checked before use (issue 48, item 2 of "what to build"): every numeric flag of
every subcommand refuses non-finite or out-of-range values in one line naming the flag (exit 2); so do
the problem settings (``--set n=1e308``, ``noise=1e308`` once raised OverflowError); an ``.npz`` that holds
text, objects or a member that is no ``.npy`` is one line (exit 2)."""

from __future__ import annotations

import argparse
import zipfile

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import INT_MAX, build_parser, main

pytestmark = pytest.mark.usefixtures("one_thread")


def numeric_flags():
    """``(command, argv without the flag, flag, type)`` for every int/float option of every subcommand."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    found = []
    for command, p in sub.choices.items():
        base = [command]
        for action in p._actions:
            if not action.option_strings and action.dest != "help":
                base.append("heat_1d")  # positional: never read, the check comes first
            elif action.required:
                base += [action.option_strings[0], "x.npz"]
        for action in p._actions:
            kind = getattr(action.type, "cast", action.type)  # PLAIN_INT reads as int
            if kind in (int, float) and action.option_strings and action.dest != "seed":
                found.append((command, base, max(action.option_strings, key=len), kind))
    return found


FLAGS = numeric_flags()


def test_the_flags_are_found():
    names = {(c, f) for c, _, f, _ in FLAGS}
    assert {("train", "--prior-fit"), ("train", "--lr"), ("train", "--threads"), ("demo", "--batch"),
            ("predict", "--threads"), ("train", "--max-memory-gb")} <= names


@pytest.mark.parametrize("command, base, flag, kind", FLAGS, ids=[f"{c}{f}" for c, _, f, _ in FLAGS])
def test_every_numeric_flag_refuses_what_is_out_of_range(capsys, command, base, flag, kind):
    values = ["nan", "inf", "-inf"] if kind is float else [str(10**20), str(-(10**20)), str(INT_MAX + 1)]
    for value in values:
        assert main([*base, f"{flag}={value}"]) == 2, value  # --lr=-inf: argparse takes -inf for a flag
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith(f"pdeinv {command}: error: {flag} {value}"), err


def test_prior_fit_inf_is_a_usage_error(capsys):
    for value in ("inf", "1e308"):  # argparse's own one line and exit 2 (SystemExit)
        with pytest.raises(SystemExit) as info:
            main(["train", "heat_1d", "--out", "x", "--prior-fit", value])
        assert info.value.code == 2 and "--prior-fit: invalid int value" in capsys.readouterr().err


@pytest.mark.parametrize("setting, says", [
    ("n=1e308", "n='1e308' is out of range; expected an integer of at most 2147483647"),
    ("n=99999999999999999999", "is out of range"),
    ("steps=1e30", "steps='1e30' is out of range"),
    ("noise=1e308", "noise='1e308' is out of range; expected a number of magnitude at most 1e+150"),
    ("kappa=-1e200", "is out of range"),
    ("noise=1e400", "noise=inf is not allowed; expected a finite number >= 0"),
])
def test_settings_out_of_range(capsys, setting, says):
    assert main(["demo", "heat_1d", "--set", setting]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err, err


@pytest.mark.parametrize("scene, settings", [("heat_1d", ["n=2"]), ("heat_2d", ["n=2"]),
                                             ("heat_1d", ["n=1", "element=P2"])])
def test_a_mesh_with_its_unknowns_at_one_point_names_n(capsys, tmp_path, scene, settings):
    """One unknown left by the boundary: the priors (relative to the unknowns' extent) had NaN widths and the
    run failed with "array must not contain infs or NaNs"; now refused at build time, naming n."""
    sets = [a for kv in settings for a in ("--set", kv)]
    out = str(tmp_path / "r")
    assert main(["train", scene, *sets, "--steps", "2", "--prior-fit", "0", "--out", out]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"error: {settings[0]} is too coarse: it leaves 1 unknown at one" in err
    assert not (tmp_path / "r").exists()
    with pytest.raises(ValueError, match=f"{settings[0]} is too coarse"):
        pdeinv.load_problem(scene, **dict(kv.split("=") for kv in settings))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("npz")
    np.savez(d / "text.npz", y=np.array([["a"] * 15] * 4))
    np.savez(d / "object.npz", y=np.array([[1, None]] * 4, dtype=object))
    np.savez(d / "meta-object.npz", y=np.ones((4, 15)), noise=np.array([None], dtype=object))
    with zipfile.ZipFile(d / "zip-of-text.npz", "w") as z:
        z.writestr("y.npy", "hello world")
    (d / "plain.npz").write_text("not a zip")
    return d


@pytest.mark.parametrize("name, says", [
    ("text", "y has dtype <U1; expected a real numeric array"),
    ("object", "y is an object array (pickled Python objects); expected an array of numbers"),
    ("meta-object", "noise is an object array"),
    ("zip-of-text", "y is not a numpy array (the archive's y.npy is not in .npy format)"),
    ("plain", "is not an .npz archive (not a zip of .npy arrays)"),
])
@pytest.mark.parametrize("command", ["classical", "train"])
def test_npz_files_that_hold_no_numbers(files, tmp_path, capsys, name, says, command):
    out = ["--out", str(tmp_path / "r")] if command == "train" else []
    assert main([command, "heat_1d", "--set", "n=16", "--data", str(files / f"{name}.npz"), *out]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and says in err, err
