"""The module paths of release 0.1, kept importable for one release.

0.2 moved the root modules into folders that follow the pipeline (``pdeinv.mesh`` is now
:mod:`pdeinv.fem.mesh`, ``pdeinv.trainer`` is :mod:`pdeinv.training.trainer`, …). A user's
``from pdeinv.mesh import unit_square`` keeps working: a finder on ``sys.meta_path`` answers an
old path with the module at its new path (the same module object, so ``isinstance`` checks and
monkeypatches agree) and warns once with a :class:`DeprecationWarning` naming the new path.
``from pdeinv import mesh`` (the short names of :mod:`pdeinv`) needs no alias and does not warn.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: old path -> new path, both relative to the package
MOVED = {
    "advection": "fem.advection", "forms": "fem.forms", "grid": "fem.grid", "mesh": "fem.mesh",
    "observe": "fem.sensors", "solvers": "fem.solvers", "autograd": "physics.bridge",
    "physics.compiled": "physics.backends.compiled", "physics.lowrank": "physics.backends.lowrank",
    "physics.modal": "physics.backends.modal", "physics.modes": "physics.backends.modes",
    "physics.device": "physics.backends.device",
    "cache": "util.cache", "memory": "util.memory", "runlock": "util.runlock", "threads": "util.threads",
    "checkpoint": "training.checkpoint", "data": "training.data", "distributed": "training.distributed",
    "evaluation": "training.evaluation", "progress": "util.progress", "stopping": "training.stopping",
    "targets": "methods.targets", "trainer": "training.trainer", "trainset": "training.trainset",
    "unseen": "training.verdict", "verdict": "training.verdict",
    "export": "io.export", "files": "util.files", "plots": "io.plots", "runs": "io.runs",
    "noise": "inverse.noise", "sampling": "problem.sampling", "scenes": "problem.scenes",
    "settings": "problem.settings", "references": "training.references",
    "precondition": "nets.whitening", "refine": "nets.refine",
    "methods.hig_fixed": "methods.hig.fixed", "methods.hig_kron": "methods.hig.kron",
    "methods.hig_layers": "methods.hig.layers", "methods.hig_randomized": "methods.hig.randomized",
    "methods.hig_routes": "methods.hig.routes", "methods.hig_structured": "methods.hig.structured",
    "commands": "cli.commands",
    **{f"commands.{m}": f"cli.commands.{m}" for m in (
        "_checks", "_folder", "_plot", "bench", "classical", "demo", "predict", "problems", "show",
        "stress", "train")},
}


class _Loader(importlib.abc.Loader):
    def __init__(self, new: str):
        self.new = new

    def create_module(self, spec):
        return importlib.import_module(self.new)

    def exec_module(self, module):
        pass


class MovedFinder(importlib.abc.MetaPathFinder):
    """Finds ``package.<old>`` for every old path in :data:`MOVED` at ``package.<new>``."""

    def __init__(self, package: str):
        self.package = package

    def find_spec(self, fullname, path=None, target=None):
        prefix = self.package + "."
        old = fullname[len(prefix):] if fullname.startswith(prefix) else None
        if old not in MOVED:
            return None
        new = prefix + MOVED[old]
        warnings.warn(f"{fullname} moved to {new}; the old path goes away in the next release",
                      DeprecationWarning, stacklevel=2)
        return importlib.util.spec_from_loader(fullname, _Loader(new))


def install(package: str) -> None:
    """Put the finder for ``package``'s old paths on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, MovedFinder) and f.package == package for f in sys.meta_path):
        sys.meta_path.append(MovedFinder(package))
