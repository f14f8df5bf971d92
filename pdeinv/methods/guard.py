"""The guard, one wrapper around any rule (optax's ``apply_if_finite``), and the last good state.

:func:`apply_if_finite` asks the rule for its update, checks it, and only then
lets the rule's transformation apply it with the step-size multiplier ``scale``.
It *rejects* (raises :class:`~pdeinv.errors.NonFiniteError`, nothing applied):

* a non-finite loss or direction (NaN/Inf);
* a finite loss above ``max_loss`` (:class:`Diverged`): the trainer passes
  ``max_loss_growth`` (default 1e3) times the lowest accepted loss so far. A loss is
  measured *before* its update, so a huge loss says the previous update blew up.

**Last good state.** The loss of step k is that of the parameters left by step
k − 1: once it passes, those parameters are known to be good. With ``snapshot`` a
:class:`Snapshot` then copies them and the rule's state (optimizer moments, step
count) before step k's update is applied. On a rejection the trainer restores it,
undoing the update that blew up (not only the rejected step), lowers the step
size and retries. The copy goes into buffers allocated once (one pass over the
parameters and optimizer state per step) and is deterministic, so a checkpoint
holding it (:meth:`Snapshot.saved`) resumes bitwise.
"""

from __future__ import annotations

import copy
import math

import torch

from ..errors import NonFiniteError
from .base import Resumable, State, describe, trainable

ADVICE = "lower the learning rate / eta, or raise tau for HIG"


class Diverged(NonFiniteError):
    """A finite loss beyond the allowed growth over the lowest one so far: rejected like a NaN."""


def apply_if_finite(rule, state: State, model: torch.nn.Module, y: torch.Tensor, scale: float = 1.0,
                    max_loss: float = math.inf, snapshot: Snapshot | None = None,
                    target: torch.Tensor | None = None):
    """One step of ``rule`` on batch ``y`` (with ``target`` if given, :mod:`pdeinv.targets`): ``(state,
    info)``; refuses a non-finite loss or update, or a loss above ``max_loss``; ``snapshot`` keeps the
    verified pre-step state (module docstring)."""
    direction, info = rule.update(state, model, y) if target is None else \
        rule.update(state, model, y, target=target)
    params = trainable(model)
    check_update(info, direction, model)
    loss = info["loss"]
    if loss > max_loss:
        raise Diverged(f"the y-loss {loss:.3g} exceeds {max_loss:.3g}, the allowed growth over the lowest "
                       f"loss so far: the previous update blew up; it is undone ({ADVICE})")
    if snapshot is not None:
        snapshot.take(rule, state, model)
    rule.transform.apply(state.transform, params, direction, scale)
    return state._replace(steps=state.steps + 1), info


def check_update(info: dict, direction, model: torch.nn.Module) -> None:
    """Raise :class:`NonFiniteError` unless ``info["loss"]`` and every direction tensor are finite."""
    loss = info.get("loss", math.nan)
    if direction is None or not math.isfinite(loss):
        raise NonFiniteError(f"the y-loss is not finite ({loss}); the update was not applied ({ADVICE})")
    given = [d for d in direction if d is not None]
    if not given or bool(torch.stack([torch.isfinite(d).all() for d in given]).all()):
        return
    names = [n for n, p in model.named_parameters() if p.requires_grad]
    for name, d in zip(names, direction, strict=True):
        if d is not None and not bool(torch.isfinite(d).all()):
            raise NonFiniteError(f"the update of {name!r} is not finite ({describe(d)}); "
                                 f"it was not applied ({ADVICE})")


class Snapshot:
    """The last verified parameters and rule state, and the step count they belong to.

    ``step`` is ``None`` until the first :meth:`take`. A rule that is not
    :class:`~pdeinv.methods.base.Resumable` has its parameters rolled back, not its state.
    """

    def __init__(self):
        self.params: list[torch.Tensor] = []
        self.rule_state: dict | None = None
        self.step: int | None = None

    @torch.no_grad()
    def take(self, rule, state: State, model: torch.nn.Module, step: int | None = None) -> None:
        params = trainable(model)
        if len(self.params) != len(params):
            self.params = [p.detach().clone() for p in params]
        else:
            for saved, p in zip(self.params, params, strict=True):
                saved.copy_(p)
        if isinstance(rule, Resumable):
            self.rule_state = copy.deepcopy(rule.state_dict(state))
        self.step = state.steps if step is None else step

    @torch.no_grad()
    def restore(self, rule, state: State, model: torch.nn.Module) -> State:
        """Copy the snapshot back into ``model`` and return the rule state it held."""
        for p, saved in zip(trainable(model), self.params, strict=True):
            p.copy_(saved)
        if self.rule_state is not None:
            state = rule.load_state_dict(state, copy.deepcopy(self.rule_state))
        return state._replace(steps=self.step)

    def saved(self) -> dict | None:
        """For a checkpoint (``None`` before the first :meth:`take`)."""
        if self.step is None:
            return None
        return {"params": self.params, "rule_state": self.rule_state, "step": self.step}

    def load(self, saved: dict | None) -> None:
        if saved is not None:
            self.params = [t.clone() for t in saved["params"]]
            self.rule_state, self.step = saved["rule_state"], int(saved["step"])
