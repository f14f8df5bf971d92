"""Built-in problems ship inside the installed package (``pdeinv.problems``), meshes included.

A non-editable install used to find no built-in problem at all: the lookup went through the
repository's top-level ``problems/``. A wheel build is too slow for the suite, so setuptools'
``build_py`` (reading ``pyproject.toml``, as a wheel build does) lays out the package in a
temporary folder and a fresh interpreter imports ``pdeinv`` from there, in another folder.
"""

import os
import subprocess
import sys
import warnings
from importlib import resources
from pathlib import Path

import setuptools

import pdeinv
from pdeinv.problem.definition import available

ROOT = Path(__file__).resolve().parents[1]
BUILTINS = sorted(p.stem for p in (ROOT / "problems").glob("*.py") if not p.stem.startswith("_"))


def _build_py(build_lib=None):
    from setuptools.config.pyprojecttoml import apply_configuration
    from setuptools.dist import Distribution

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # setuptools' deprecation notes about the license table
        dist = apply_configuration(Distribution(), ROOT / "pyproject.toml")
    dist.script_name = "setup.py"
    cmd = dist.get_command_obj("build_py")
    if build_lib is not None:
        cmd.build_lib, cmd.compile = str(build_lib), False
    cmd.ensure_finalized()
    return dist, cmd


def test_installed_layout_finds_every_builtin_from_another_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)  # setuptools resolves the package folders against the project root
    _, cmd = _build_py(tmp_path / "lib")
    cmd.run()
    meshes = [f.name for f in (ROOT / "problems/meshes").iterdir() if f.suffix == ".msh"]
    assert meshes and all((tmp_path / "lib/pdeinv/problems/meshes" / f).is_file() for f in meshes)
    env = {k: v for k, v in os.environ.items() if k != "PDEINV_PROBLEMS"}
    env["PYTHONPATH"] = str(tmp_path / "lib")  # ahead of the editable install's finder
    code = ("import pdeinv, pdeinv.problem as pp; print(pdeinv.__file__); print(pp.available()); "
            "print(pdeinv.load_problem('heat_plate').N)")
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    lines = res.stdout.strip().splitlines()
    where, names, n = lines[0], lines[1], lines[-1]
    assert Path(where).is_relative_to(tmp_path / "lib")
    assert eval(names) == BUILTINS
    assert int(n) > 0  # heat_plate read its mesh from the package


def test_builtins_are_found_through_the_package(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("PDEINV_PROBLEMS", raising=False)
    folder = Path(str(resources.files("pdeinv.problems")))
    assert sorted(p.stem for p in folder.glob("*.py") if not p.stem.startswith("_")) == BUILTINS
    assert available() == BUILTINS
    assert pdeinv.load_problem("heat_1d", n=16).N == 15


def test_user_folders_come_before_the_builtins(tmp_path, monkeypatch):
    (tmp_path / "heat_1d.py").write_text(
        "from pdeinv.problem import load_problem\n"
        f"def make(**kw):\n    p = load_problem({str(ROOT / 'problems' / 'heat_2d.py')!r}, n=4)\n"
        "    p.name = 'mine'\n    return p\n")
    monkeypatch.setenv("PDEINV_PROBLEMS", str(tmp_path))
    assert pdeinv.load_problem("heat_1d").name == "mine"


def test_every_pdeinv_subpackage_is_listed_in_pyproject(monkeypatch):
    """The package list is written out (because of the problems/ mapping): a new subpackage must join it."""
    monkeypatch.chdir(ROOT)
    dist, _ = _build_py()
    found = set(setuptools.find_packages(include=["pdeinv*"])) | {"pdeinv.problems", "pdeinv.problems.meshes"}
    assert set(dist.packages) == found, f"add {sorted(found - set(dist.packages))} to pyproject.toml"


def test_a_problem_module_imports_its_sibling_and_is_found_by_name_in_the_current_folder(tmp_path,
                                                                                        monkeypatch):
    """A helper next to the problem module imports as it would next to a script (it used to end in a
    ModuleNotFoundError traceback); ``pdeinv train myscene`` finds ./myscene.py by name."""
    from pdeinv.cli import main

    (tmp_path / "my_helper_mod.py").write_text("N_CELLS = 8\n")
    (tmp_path / "myscene.py").write_text(
        "from my_helper_mod import N_CELLS\n"
        f"from pdeinv.problem import load_problem\n"
        f"def make(**kw):\n    return load_problem({str(ROOT / 'problems' / 'heat_1d.py')!r}, n=N_CELLS)\n")
    monkeypatch.syspath_prepend(str(ROOT))  # keep sys.path restorable: the loader prepends tmp_path
    other = tmp_path / "elsewhere"
    other.mkdir()
    monkeypatch.chdir(other)
    monkeypatch.delenv("PDEINV_PROBLEMS", raising=False)
    assert pdeinv.load_problem(str(tmp_path / "myscene.py")).N == 7
    monkeypatch.chdir(tmp_path)
    assert pdeinv.load_problem("myscene").N == 7 and "myscene" not in available()
    assert main(["train", "--prior-fit", "0", "myscene", "--steps", "1", "--n-train", "16", "--n-test", "4",
                 "--export-samples", "0", "--out", str(tmp_path / "run")]) == 0
