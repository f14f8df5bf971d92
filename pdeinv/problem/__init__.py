"""The problem: :class:`Problem` and the problem modules (:mod:`.definition`), the built-in scene
builders (:mod:`.scenes`), settings (:mod:`.settings`), priors (:mod:`.sampling`) and noise
(:mod:`.noise`). Names are imported on first use, so ``from pdeinv.problem import settings``
costs no torch."""

import importlib

_WHERE = dict.fromkeys(["Problem", "available", "load_problem"], "definition")

__all__ = ["Problem", "available", "load_problem"]


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'pdeinv.problem' has no attribute {name!r}")
    value = vars(importlib.import_module(f".{_WHERE[name]}", __name__))[name]
    globals()[name] = value
    return value
