"""Update rules as strategy objects that compute an update and never apply it (see :mod:`.base`):
``state = rule.init(problem, model)``, ``direction, info = rule.update(state, model, y)``;
:func:`.guard.apply_if_finite` checks and applies it with ``rule.transform``; a run's :class:`.guard.Guard`
owns the step size, the failure budget and the roll-back to the last good state.

Names are imported on first use, so :mod:`.names` (the CLI's method names) costs no torch import.
"""

import importlib

_WHERE = {**dict.fromkeys(["NonFiniteError", "Resumable", "State", "Update", "UpdateRule", "adam", "sgd"],
                          "base"),
          "GD": "gd", "Guard": "guard", "apply_if_finite": "guard", "HIG": "hig", "SIP": "sip",
          "Supervised": "supervised"}

__all__ = ["GD", "HIG", "SIP", "Supervised", "Guard", "NonFiniteError", "Resumable", "State", "Update",
           "UpdateRule", "adam", "apply_if_finite", "sgd"]


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'pdeinv.methods' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)  # hig is lazy too
    globals()[name] = value
    return value
