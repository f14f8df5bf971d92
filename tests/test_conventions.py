"""Small conventions a new user meets in the first hour (issue 36): every flag of ``pdeinv train`` says
what it does, errors print with ``%.3g`` (``x_err 0.0000`` once hid 6e-11), the package declares its
type hints (PEP 561 ``py.typed``), ``--quiet`` / ``--verbose`` set the level of the ``pdeinv`` logger."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import pdeinv
from pdeinv.cli import build_parser, main

ROOT = Path(pdeinv.__file__).resolve().parent


@pytest.mark.parametrize("command", ["train",
                                     "predict", "classical", "show", "bench", "stress", "demo"])
def test_every_flag_has_a_help_string(command):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    bare = [a.option_strings[0] for a in sub._actions if a.option_strings and not a.help
            and a.option_strings[0] != "--help"]
    assert bare == [], f"pdeinv {command}: flags without help: {bare}"


def test_tiny_errors_are_printed_in_three_significant_digits(tmp_path, capsys):
    """wave_1d with the whitened default network: SIP solves it to rounding."""
    assert main(["train", "--prior-fit", "0",
                 "wave_1d", "--set", "n=16", "--set", "steps=10", "--n-train", "32", "--n-test",
                 "8", "--threads", "1", "--export-samples", "0", "--out", str(tmp_path / "run")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    x_err = re.search(r"x_err (\S+),", line).group(1)
    assert float(x_err) < 1e-4 and "e-" in x_err, line  # not "0.0000"


def test_the_package_declares_its_type_hints():
    assert (ROOT / "py.typed").is_file()
    assert '"pdeinv" = ["py.typed"]' in (ROOT.parent / "pyproject.toml").read_text()


@pytest.mark.parametrize("flag, shown", [("--quiet", []), (None, ["built"]),
                                         ("--verbose", ["built", "backend"])])
def test_quiet_and_verbose(flag, shown, capsys):
    from pdeinv.cli.commands import build_problem
    from pdeinv.cli.logs import cli_logging

    args = build_parser().parse_args(["demo", "heat_1d", *([flag] if flag else [])])
    with cli_logging(args):
        build_problem("demo", "heat_1d", ["n=8"], after_s=0.0)
    err = capsys.readouterr().err
    assert [w for w in ("built", "backend") if w in err] == shown, err
    assert build_parser().parse_args(["train", "x", "--out", "o", "-q"]).quiet
