"""Update rules as strategy objects that compute an update and never apply it (see :mod:`.base`):
``state = rule.init(problem, model)``, ``direction, info = rule.update(state, model, y)``;
:func:`.guard.apply_if_finite` checks and applies it with ``rule.transform``."""

from .base import NonFiniteError, Resumable, State, Update, UpdateRule, adam, sgd
from .gd import GD
from .guard import apply_if_finite
from .hig import HIG
from .sip import SIP

__all__ = ["GD", "HIG", "SIP", "NonFiniteError", "Resumable", "State", "Update", "UpdateRule", "adam",
           "apply_if_finite", "sgd"]
