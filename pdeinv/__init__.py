"""pdeinv: PDE inverse problems on finite elements.

The pipeline, upstream to downstream: mesh → forms → physics (operators with
exact adjoints) → autograd bridge / inverse simulators → update rules → trainer.

Names are imported on first use (PEP 562), so ``import pdeinv`` and ``pdeinv --help``
do not pay for torch (measured: ``pdeinv --help`` 3.2 s → 0.3 s).

``pdeinv.train`` is the function :func:`pdeinv.training.trainer.train`; the trainer's module is
:mod:`pdeinv.training.trainer`.
"""

import importlib

#: public name -> the module that defines it ("=path": the name is that submodule itself)
_WHERE = {
    # the layers (``pdeinv.io.export`` works without importing ``pdeinv.io`` first) and the mesh builders
    **{k: f"={k}" for k in ("util", "fem", "physics", "inverse", "methods", "training", "io", "nets")},
    "mesh": "=fem.mesh",
    **dict.fromkeys(["Problem", "available", "load_problem"], "problem"),
    "apply": "physics.bridge",
    **dict.fromkeys(["GD", "HIG", "SIP", "Supervised", "adam", "sgd"], "methods"),
    **dict.fromkeys(["Result", "Trainer", "train"], "training.trainer"),
    "Checkpoint": "training.checkpoint",
    **dict.fromkeys(["DiscrepancyStop", "PlateauStop"], "training.stopping"),
    **dict.fromkeys(["load_run", "save_run"], "io.runs"),
    **dict.fromkeys(["Plan", "plan"], "training.plan"),
    "PriorStage": "training.plan",
}

#: the names a user calls; everything else is reached by its module path (``pdeinv.inverse.TikhonovCG``)
__all__ = sorted(_WHERE)

#: the short names a problem module imports (``from pdeinv import mesh, scenes, settings``), not in __all__,
#: and the posterior layer (``pdeinv.posterior.predictive``)
_WHERE.update({"scenes": "=problem.scenes", "nonlinear_scenes": "=problem.nonlinear_scenes",
               "settings": "=problem.settings", "observe": "=fem.sensors", "posterior": "=posterior"})
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

