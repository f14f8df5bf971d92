"""pdeinv: PDE inverse problems on finite elements.

The pipeline, upstream to downstream: mesh → forms → physics (operators with
exact adjoints) → autograd bridge / inverse simulators → update rules → trainer.

Names are imported on first use (PEP 562), so ``import pdeinv`` and ``pdeinv --help``
do not pay for torch (measured: ``pdeinv --help`` 3.2 s → 0.3 s). ``pdeinv.train`` is
the function :func:`pdeinv.train.train`, as before, also after ``import pdeinv.train``.
"""

import importlib
import sys
import types

#: public name -> the submodule that defines it (submodules themselves map to None)
_WHERE = {
    "export": None, "mesh": None, "observe": None, "plots": None, "nets": None, "runs": None,
    "references": None, "targets": None, "threads": None, "settings": None, "scenes": None,
    "load_run": "runs", "save_run": "runs",
    "apply": "autograd", "Checkpoint": "checkpoint", "Discretization": "forms", "discretize": "forms",
    **dict.fromkeys(["Discrepancy", "FixedAlpha", "ModalTikhonov", "RelativeAlpha", "StateReversal",
                     "SpectralTikhonov", "TikhonovCG", "TimeReversal", "default_inverse",
                     "CompiledInverse"], "inverse"),
    **dict.fromkeys(["GD", "HIG", "SIP", "NonFiniteError", "adam", "sgd"], "methods"),
    **dict.fromkeys(["Net", "mlp", "reduced", "whitened", "zero_last_layer"], "nets"),
    "estimate_noise": "noise", "sensor_matrix": "observe",
    **dict.fromkeys(["Heat", "HeatSensors", "Leapfrog", "LinearOperator", "Matrix", "Modal", "Stepping",
                     "Wave", "WaveSensors", "Propagator"], "physics"),
    "Whitening": "precondition",
    **dict.fromkeys(["Problem", "available", "load_problem"], "problem"),
    **dict.fromkeys(["AMGCG", "Cholesky", "SuperLU", "amg_cg", "default_solver", "solver_for"], "solvers"),
    "DiscrepancyStop": "stopping",
    **dict.fromkeys(["Result", "Trainer", "train"], "train"),
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


class _Package(types.ModuleType):
    """Keeps ``pdeinv.train`` the function when the submodule ``pdeinv.train`` is imported (the
    import system sets the package attribute to the module; the eager ``from .train import train``
    used to overwrite it)."""

    def __setattr__(self, name, value):
        if name == "train" and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
