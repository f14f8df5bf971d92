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


def test_the_modules_users_reach_for_are_attributes():
    """``pdeinv.references`` once raised AttributeError (``from pdeinv import references`` worked)."""
    assert pdeinv.references.tikhonov_best and pdeinv.targets.SpectralWiener and pdeinv.threads.limit


def test_version(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"pdeinv {pdeinv.__version__}"

