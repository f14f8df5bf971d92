"""Update rules as strategy objects: ``state = rule.init(problem, model)``,
``state, info = rule.step(state, model, y_target)`` (see :mod:`.base`)."""

from .base import NonFiniteError, UpdateRule, adam, sgd
from .gd import GD
from .hig import HIG
from .sip import SIP

__all__ = ["GD", "HIG", "SIP", "NonFiniteError", "UpdateRule", "adam", "sgd"]
