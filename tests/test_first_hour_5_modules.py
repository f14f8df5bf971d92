"""A user's problem module fails in one line (issue 48, item 1): a syntax error, a ``make`` that raises, a
missing import, a module that exits or returns no Problem: one line naming the file, the line and the
exception's message, exit 2, the traceback only with ``-v``; the Python API raises the same message as a
``ValueError``. Empty or blank problem names are a usage error. A module found by name in the current
folder (documented: docs/problems.md) says so when it fails."""

from __future__ import annotations

import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.problem.definition import ProblemModuleError

pytestmark = pytest.mark.usefixtures("one_thread")

HEAT = ("from pdeinv import load_problem\n\n\n"
        "def make(**overrides):\n    return load_problem('heat_1d', n=8)\n")

#: name -> (module text, what the line says after the file and line)
MODULES = {
    "syntax": ("def make(**overrides:\n    pass\n", 1, "SyntaxError: '(' was never closed"),
    "raises": ("import math\n\n\ndef make(**overrides):\n    raise RuntimeError('boom in make')\n", 5,
               "in make: RuntimeError: boom in make"),
    "deep": ("def helper():\n    return {}['kappa']\n\n\ndef make(**overrides):\n    return helper()\n", 2,
             "in helper: KeyError: 'kappa'"),
    "missing": ("import not_a_module_xyz\n\n\ndef make(**overrides):\n    pass\n", 1,
                "ModuleNotFoundError: No module named 'not_a_module_xyz'"),
    "exits": ("import sys\n\n\ndef make(**overrides):\n    sys.exit(0)\n", 5,
              "in make: called sys.exit(0); expected make(**overrides) to return a pdeinv.Problem"),
    "exits-at-import": ("raise SystemExit(3)\n", 1, "called sys.exit(3)"),
    "returns-none": ("def make(**overrides):\n    return None\n", None,
                     "make() returned NoneType; expected a pdeinv.Problem"),
    "user-value-error": ("def make(**overrides):\n    raise ValueError('kappa must be small')\n", 2,
                         "in make: ValueError: kappa must be small"),
    "bad-operator": ("import pdeinv\n\n\ndef make(**overrides):\n"
                     "    p = pdeinv.load_problem('heat_1d', n=8)\n"
                     "    return pdeinv.Problem('x', p.disc, 'not an operator', p.sampler)\n", 6,
                     "TypeError: operator=str is not allowed"),
}


@pytest.mark.parametrize("name", sorted(MODULES))
def test_a_broken_module_is_one_line_and_exit_2(tmp_path, capsys, name):
    text, line, says = MODULES[name]
    module = tmp_path / f"{name.replace('-', '_')}.py"
    module.write_text(text)
    out = tmp_path / "run"
    code = main(["train", str(module), "--steps", "1", "--prior-fit", "0", "-q", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    where = f"problem module {str(module)!r}" + (f", line {line}" if line else "")
    assert err.startswith(f"pdeinv train: error: {where}"), err
    assert says in err, err
    assert not out.exists()
    with pytest.raises(ValueError, match="problem module") as info:  # the API: the same line
        pdeinv.load_problem(module)
    assert isinstance(info.value, (ProblemModuleError, ValueError)) and says in str(info.value)


def test_verbose_shows_the_traceback(tmp_path, capsys):
    module = tmp_path / "raises.py"
    module.write_text(MODULES["raises"][0])
    assert main(["classical", str(module), "--data", str(tmp_path / "d.npz"), "-v"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and "RuntimeError: boom in make" in err
    assert err.splitlines()[-1].startswith(f"pdeinv classical: error: problem module {str(module)!r}, line 5")


def test_a_module_that_works_still_loads(tmp_path):
    module = tmp_path / "fine.py"
    module.write_text(HEAT)
    assert pdeinv.load_problem(module).N == 7


def test_settings_errors_keep_pdeinvs_own_message(capsys):
    """A setting refused by pdeinv.problem.settings (inside a built-in's make) is not a module failure."""
    assert main(["demo", "heat_1d", "--set", "n=abc"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "problem module" not in err and "n" in err, err


@pytest.mark.parametrize("command", ["train", "demo", "classical"])
@pytest.mark.parametrize("name", ["", "  "])
def test_an_empty_problem_name_is_a_usage_error(tmp_path, capsys, command, name):
    extra = {"train": ["--out", str(tmp_path / "r")], "classical": ["--data", str(tmp_path / "d.npz")],
             "demo": []}[command]
    assert main([command, name, *extra]) == 2
    err = capsys.readouterr().err
    assert err == f"pdeinv {command}: error: PROBLEM {name!r} is empty; expected a problem name (pdeinv " \
                  "problems lists them) or the path of a module file with make(**overrides)\n"
    with pytest.raises(ValueError, match=r"name_or_path=.* is empty"):
        pdeinv.load_problem(name)


def test_a_module_found_in_the_current_folder_says_where_it_was_found(tmp_path, monkeypatch, capsys):
    (tmp_path / "sneaky.py").write_text(MODULES["raises"][0])
    monkeypatch.chdir(tmp_path)
    assert main(["train", "sneaky", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "found by name in the current folder" in err, err
