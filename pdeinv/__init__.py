"""pdeinv: PDE inverse problems on finite elements.

The pipeline, upstream to downstream: mesh → forms → physics (operators with
exact adjoints) → autograd bridge / inverse simulators → update rules → trainer.

Names are imported on first use (PEP 562), so ``import pdeinv`` and ``pdeinv --help``
do not pay for torch (measured: ``pdeinv --help`` 3.2 s → 0.3 s).

``pdeinv.train`` is the function :func:`pdeinv.trainer.train`; the trainer's module is
:mod:`pdeinv.trainer` (it was ``pdeinv/train.py``, whose name the function shadowed). The old
module path still imports, for one release: ``sys.modules["pdeinv.train"]`` is an alias of
:mod:`pdeinv.trainer` registered here, so ``from pdeinv.train import Trainer`` works and, the alias
never being loaded as a submodule, never rebinds ``pdeinv.train`` (the function).
"""

import importlib
import sys
import types

#: public name -> the submodule that defines it (submodules themselves map to None)
_WHERE = {
    "export": None, "mesh": None, "observe": None, "plots": None, "nets": None, "runs": None,
    "references": None, "targets": None, "threads": None, "settings": None, "scenes": None, "verdict": None,
    "FailedRun": "verdict",
    "load_run": "runs", "save_run": "runs",
    "apply": "autograd", "Checkpoint": "checkpoint", "Discretization": "forms", "discretize": "forms",
    **dict.fromkeys(["Discrepancy", "FixedAlpha", "ModalTikhonov", "RelativeAlpha", "StateReversal",
                     "SpectralTikhonov", "TikhonovCG", "TimeReversal", "default_inverse",
                     "CompiledInverse"], "inverse"),
    **dict.fromkeys(["GD", "HIG", "SIP", "Supervised", "NonFiniteError", "adam", "sgd"], "methods"),
    **dict.fromkeys(["Net", "mlp", "reduced", "whitened", "zero_last_layer"], "nets"),
    "estimate_noise": "noise", "sensor_matrix": "observe",
    **dict.fromkeys(["Heat", "Leapfrog", "LinearOperator", "Matrix", "Modal", "Stepping", "Wave",
                     "Propagator", "Physics", "ReactionHeat", "SineGordon"], "physics"),
    "Whitening": "precondition",
    **dict.fromkeys(["Problem", "available", "load_problem"], "problem"),
    **dict.fromkeys(["AMGCG", "Cholesky", "SuperLU", "amg_cg", "default_solver", "solver_for"], "solvers"),
    "DiscrepancyStop": "stopping",
    **dict.fromkeys(["Result", "Trainer", "train"], "trainer"),
}

__all__ = sorted(_WHERE)
__version__ = "0.1.0"


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'pdeinv' has no attribute {name!r}")
    module = importlib.import_module(f".{_WHERE[name] or name}", __name__)
    value = module if _WHERE[name] is None else getattr(module, name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Alias(types.ModuleType):
    """``pdeinv.train`` as a module path: the names of :mod:`pdeinv.trainer` and its seed streams
    (:mod:`pdeinv.trainset`), loaded on first use; deprecated: import from those modules."""

    def __getattr__(self, name: str):
        if name.startswith("__"):  # inspect.getmodule asks every module for __file__: import nothing
            raise AttributeError(f"module 'pdeinv.train' has no attribute {name!r}")
        for module in ("trainer", "trainset"):
            value = getattr(importlib.import_module(f"{__name__}.{module}"), name, self)
            if value is not self:
                return value
        raise AttributeError(f"module 'pdeinv.train' has no attribute {name!r}")


sys.modules.setdefault(f"{__name__}.train", _Alias(f"{__name__}.train", _Alias.__doc__))
