"""pdeinv: PDE inverse problems on finite elements.

The pipeline, upstream to downstream: mesh → forms → physics (operators with
exact adjoints) → autograd bridge / inverse simulators → update rules → trainer.

Names are imported on first use (PEP 562), so ``import pdeinv`` and ``pdeinv --help``
do not pay for torch (measured: ``pdeinv --help`` 3.2 s → 0.3 s).

``pdeinv.train`` is the function :func:`pdeinv.training.trainer.train`; the trainer's module is
:mod:`pdeinv.training.trainer`.
"""

import importlib

#: public name -> the module that defines it (public submodules map to their module path)
_WHERE = {
    **{name: f"={path}" for name, path in {
        "export": "io.export", "mesh": "fem.mesh", "observe": "fem.sensors", "plots": "io.plots",
        "nets": "nets", "runs": "io.runs", "references": "training.references", "targets": "methods.targets",
        "threads": "util.threads", "settings": "problem.settings", "scenes": "problem.scenes",
        "verdict": "training.verdict", "nonlinear_scenes": "problem.nonlinear_scenes",
        # the layers (``pdeinv.io.export`` works without importing ``pdeinv.io`` first)
        **{k: k for k in ("util", "fem", "physics", "inverse", "methods", "training", "io")}}.items()},
    "FailedRun": "training.verdict",
    "load_run": "io.runs", "save_run": "io.runs",
    "apply": "physics.bridge", "Checkpoint": "training.checkpoint", "Discretization": "fem.forms",
    "discretize": "fem.forms",
    **dict.fromkeys(["Discrepancy", "FixedAlpha", "ModalTikhonov", "RelativeAlpha", "StateReversal",
                     "SpectralTikhonov", "TikhonovCG", "TimeReversal", "default_inverse"], "inverse"),
    **dict.fromkeys(["GD", "HIG", "SIP", "Supervised", "NonFiniteError", "adam", "sgd"], "methods"),
    **dict.fromkeys(["Net", "mlp", "reduced", "whitened", "zero_last_layer"], "nets"),
    "estimate_noise": "inverse.noise", "sensor_matrix": "fem.sensors",
    **dict.fromkeys(["Heat", "Leapfrog", "LinearOperator", "Matrix", "Modal", "Stepping", "Wave",
                     "Propagator", "Physics", "ReactionHeat", "SineGordon"], "physics"),
    "Whitening": "nets.whitening",
    **dict.fromkeys(["Problem", "available", "load_problem"], "problem"),
    **dict.fromkeys(["AMGCG", "Cholesky", "SuperLU", "amg_cg", "default_solver", "solver_for"],
                    "fem.solvers"),
    "DiscrepancyStop": "training.stopping",
    "PlateauStop": "training.stopping",
    **dict.fromkeys(["Result", "Trainer", "train"], "training.trainer"),
}

__all__ = sorted(_WHERE)
__version__ = "0.1.0"


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'pdeinv' has no attribute {name!r}")
    where = _WHERE[name]
    module = importlib.import_module(f".{where.lstrip('=')}", __name__)
    value = module if where.startswith("=") else getattr(module, name)  # a lazy package's names too
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))

