"""Files a user keeps: run folders (:mod:`.runs`), predictions and
meshes out (:mod:`.export`) and pictures (:mod:`.plots`)."""

import importlib

_SUBMODULES = ("export", "plots", "runs")


def __getattr__(name: str):
    """``pdeinv.io.export`` etc. after ``import pdeinv`` alone: the submodule, imported on first use."""
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
