"""Every public name of ``pdeinv`` resolves (lazily, PEP 562), and the CLI says its version."""

import types

import pytest

import pdeinv
from pdeinv.cli import main


@pytest.mark.parametrize("name", pdeinv.__all__)
def test_every_public_name_resolves(name):
    value = getattr(pdeinv, name)
    module = isinstance(value, types.ModuleType)
    # a public module is the one at its path
    where = pdeinv._WHERE[name]
    assert value is not None and (not module or value.__name__ == f"pdeinv.{where.lstrip('=')}")


def test_the_public_names_are_few():
    """``__all__`` lists what a user calls (at most 30 names); the rest is reached by its module path."""
    assert len(pdeinv.__all__) <= 30 and set(pdeinv.__all__) <= set(pdeinv._WHERE)
    assert pdeinv.io.export.predict and pdeinv.inverse.TikhonovCG and pdeinv.physics.Heat


@pytest.mark.parametrize("name", ["mesh", "scenes", "settings", "nonlinear_scenes", "observe"])
def test_the_short_names_problem_modules_import(name):
    """``from pdeinv import mesh, scenes, settings`` (problems/*.py), not listed in ``__all__``."""
    value = getattr(pdeinv, name)
    assert isinstance(value, types.ModuleType) and value.__name__ == f"pdeinv.{pdeinv._WHERE[name][1:]}"


def test_version(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"pdeinv {pdeinv.__version__}"

