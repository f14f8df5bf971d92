"""What an update rule declares, checked once: the trainer, the guard, checkpoints and ``torchrun`` ask
the declaration and never probe the object's attributes or signatures.

Every rule has the minimal protocol (:class:`~.base.UpdateRule`): ``name``, ``transform``,
``init(problem, model)`` and ``update(state, model, y)``. :class:`~.base.Rule` (GD, SIP, HIG,
Supervised) declares the rest, with these defaults:

========================  ===================================================================
``accepts_target``        True: ``update(..., target=)`` fits ``P f(y)`` to a denoised target
``resumable``             True: ``state_dict`` / ``load_state_dict`` / ``hyperparameters``
``needs_fields``          False: it fits the rows' true fields ``x`` (Supervised: no fresh draws)
``calibrate(state, …)``   measures what it needs on the first batch; default: nothing
``default_target()``      the target ``target="auto"`` means; ``None``: the trainer's Wiener filter
``data_parallel(sum, n)`` the rule on each of n ranks (directions averaged); default itself
========================  ===================================================================

A rule written to the minimal protocol only (a user's own object, not a :class:`~.base.Rule`) is
wrapped by :func:`declared` into :class:`Foreign`, which declares for it: no target and not
resumable (unless the object says ``accepts_target = True`` / ``resumable = True``, the latter with
its own ``state_dict``, ``load_state_dict`` and ``hyperparameters``), no calibration, no own target,
and no data-parallel form. An object without ``init``/``update``/``transform`` is refused there with a
``TypeError`` naming what is missing.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch

from .base import Rule, State, Update

#: the minimal protocol's members
REQUIRED = ("init", "update", "transform")


@runtime_checkable
class Steps(Protocol):
    """The methods of the minimal protocol (``transform`` is its data member)."""

    def init(self, problem, model): ...

    def update(self, state, model, y): ...


class Foreign(Rule):
    """A rule of the minimal protocol, with the declarations it does not make (module docstring)."""

    def __init__(self, rule):
        missing = [m for m in REQUIRED if m not in dir(rule)]
        if missing or not isinstance(rule, Steps):
            raise TypeError(f"rule={rule!r} is not an update rule: it has no {', '.join(missing)}; expected "
                            "pdeinv.GD(), pdeinv.SIP(), pdeinv.HIG(), pdeinv.Supervised(), a method name "
                            "('gd', 'adam', 'sip', 'hig', 'supervised') or an object with init(problem, "
                            "model), update(state, model, y) and a transform")
        self.inner = rule
        self.name = str(getattr(rule, "name", type(rule).__name__))  # optional, as the two below
        self.accepts_target = bool(getattr(rule, "accepts_target", False))
        self.resumable = bool(getattr(rule, "resumable", False))  # then its own state_dict & co.
        self.transform = rule.transform

    def init(self, problem, model: torch.nn.Module) -> State:
        return self.inner.init(problem, model)

    def update(self, state: State, model: torch.nn.Module, y: torch.Tensor,
               target: torch.Tensor | None = None) -> Update:
        if target is None:
            return self.inner.update(state, model, y)
        return self.inner.update(state, model, y, target=target)

    def settings(self) -> dict:
        return {}

    def state_dict(self, state: State) -> dict:
        return self.inner.state_dict(state)

    def load_state_dict(self, state: State, sd: dict) -> State:
        return self.inner.load_state_dict(state, sd)

    def hyperparameters(self) -> dict:
        return self.inner.hyperparameters()

    def data_parallel(self, sum_over, processes: int) -> None:
        return None


def declared(rule) -> Rule:
    """``rule`` as a :class:`~.base.Rule`: itself if it is one, else wrapped in :class:`Foreign`."""
    return rule if isinstance(rule, Rule) else Foreign(rule)
