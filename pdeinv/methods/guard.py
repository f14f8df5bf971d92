"""The non-finite guard, one wrapper around any rule (optax's ``apply_if_finite``).

:func:`apply_if_finite` asks the rule for its update, checks the loss and every
direction tensor for NaN/Inf, and only then lets the rule's transformation apply
it with the step-size multiplier ``scale``. A non-finite loss or direction raises
:class:`~pdeinv.errors.NonFiniteError` with the parameters, the optimizer state
and the step count exactly as they were: nothing was applied. The caller (the
trainer) owns ``scale``: it lowers it after a rejected step and checkpoints it.
"""

from __future__ import annotations

import math

import torch

from ..errors import NonFiniteError
from .base import State, describe, trainable


def apply_if_finite(rule, state: State, model: torch.nn.Module, y: torch.Tensor, scale: float = 1.0):
    """One step of ``rule`` on batch ``y``: ``(state, info)``; refuses a non-finite loss or update."""
    direction, info = rule.update(state, model, y)
    params = trainable(model)
    check_update(info, direction, model)
    rule.transform.apply(state.transform, params, direction, scale)
    return state._replace(steps=state.steps + 1), info


def check_update(info: dict, direction, model: torch.nn.Module) -> None:
    """Raise :class:`NonFiniteError` unless ``info["loss"]`` and every direction tensor are finite."""
    loss = info.get("loss", math.nan)
    if direction is None or not math.isfinite(loss):
        raise NonFiniteError(f"the y-loss is not finite ({loss}); the update was not applied "
                             "(lower the learning rate / eta, or raise tau for HIG)")
    given = [d for d in direction if d is not None]
    if not given or bool(torch.stack([torch.isfinite(d).all() for d in given]).all()):
        return
    names = [n for n, p in model.named_parameters() if p.requires_grad]
    for name, d in zip(names, direction, strict=True):
        if d is not None and not bool(torch.isfinite(d).all()):
            raise NonFiniteError(f"the update of {name!r} is not finite ({describe(d)}); "
                                 "it was not applied (lower the learning rate / eta, or raise tau for HIG)")
