"""Every public name of ``pdeinv`` resolves (lazily, PEP 562), and the CLI says its version."""

import types

import pytest

import pdeinv
from pdeinv.cli import main


@pytest.mark.parametrize("name", pdeinv.__all__)
def test_every_public_name_resolves(name):
    value = getattr(pdeinv, name)
    module = isinstance(value, types.ModuleType)
    # a public module is the one at its path (the short name, or the layer it moved into in 0.2)
    where = pdeinv._WHERE[name]
    assert value is not None and (not module or value.__name__ == f"pdeinv.{where.lstrip('=')}")


def test_the_modules_users_reach_for_are_attributes():
    """``pdeinv.references`` once raised AttributeError (``from pdeinv import references`` worked)."""
    assert pdeinv.references.tikhonov_best and pdeinv.targets.SpectralWiener and pdeinv.threads.limit


def test_version(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"pdeinv {pdeinv.__version__}"


def test_train_is_the_function_and_the_old_module_path_an_alias():
    """Issue 24: the module ``pdeinv/train.py`` shadowed by the function ``pdeinv.train`` is now
    ``pdeinv.training.trainer``; ``from pdeinv.train import …`` still resolves (an alias, for one release) and
    importing it never rebinds ``pdeinv.train``."""
    import sys
    from pathlib import Path

    import pdeinv.train  # noqa: F401
    from pdeinv.train import TEST_DATA, Trainer, seed_stream

    import pdeinv.training.trainer
    import pdeinv.training.trainset

    assert pdeinv.train is pdeinv.training.trainer.train and Trainer is pdeinv.training.trainer.Trainer
    trainset = pdeinv.training.trainset
    assert seed_stream is trainset.seed_stream and TEST_DATA == trainset.TEST_DATA
    assert not (Path(pdeinv.__file__).parent / "train.py").exists()
    with pytest.raises(ImportError, match="nothing"):
        from pdeinv.train import nothing  # noqa: F401
    assert not hasattr(sys.modules["pdeinv.train"], "__file__")  # inspect.getmodule's probe imports nothing
