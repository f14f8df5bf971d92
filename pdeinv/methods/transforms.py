"""Transformations: how a rule's direction becomes a change of the parameters, scaled by ``s``.

The step-size multiplier ``s`` (1 at the start, lowered by the non-finite guard)
enters here and only here:

* :class:`OptimizerStep`: the direction is gradient-like; it is written to ``.grad``
  and a torch optimizer steps with learning rate ``s · lr`` (GD, SIP's proxy step).
  Its state (moments, step counts, param-group settings) is the optimizer's own
  ``state_dict``, restored bitwise.
* :class:`Add`: the direction is the step itself: ``θ ← θ + s · d`` (HIG). No state.

A transformation is a strategy object::

    tstate = transform.init(params)                      # once per run
    transform.apply(tstate, params, direction, s)        # in place, under no_grad
    transform.state_dict(tstate) / load_state_dict(tstate, sd) / hyperparameters()
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .base import OptimizerFactory, make_optimizer, optimizer_hyperparameters


@dataclass(frozen=True)
class OptimizerStep:
    """A torch optimizer fed with the direction as gradient, at learning rate ``s · lr``."""

    factory: OptimizerFactory

    def init(self, params: list) -> torch.optim.Optimizer:
        opt = make_optimizer(self.factory, params)
        for group in opt.param_groups:
            group["configured_lr"] = group["lr"]  # the lr the multiplier scales (saved with the group)
        return opt

    def apply(self, opt: torch.optim.Optimizer, params: list, direction, scale: float) -> None:
        for group in opt.param_groups:
            group["lr"] = group["configured_lr"] * scale
        for p, d in zip(params, direction, strict=True):
            p.grad = d
        opt.step()
        opt.zero_grad(set_to_none=True)

    def state_dict(self, opt: torch.optim.Optimizer) -> dict:
        return opt.state_dict()

    def load_state_dict(self, opt: torch.optim.Optimizer, sd: dict) -> torch.optim.Optimizer:
        configured = [g["configured_lr"] for g in opt.param_groups]
        opt.load_state_dict(sd)
        for group, lr in zip(opt.param_groups, configured, strict=True):
            group["configured_lr"] = lr  # this run's configuration (identical: the identity checked it)
        return opt

    def hyperparameters(self) -> dict:
        return optimizer_hyperparameters(self.factory)


@dataclass(frozen=True)
class Add:
    """``θ ← θ + s · d``: the direction is the step (cast to each parameter's dtype)."""

    def init(self, params: list) -> None:
        if not params:
            raise ValueError("the model has no trainable parameters")

    @torch.no_grad()
    def apply(self, _state, params: list, direction, scale: float) -> None:
        for p, d in zip(params, direction, strict=True):
            if d is not None:
                p.add_((d if scale == 1.0 else scale * d).to(p.dtype))

    def state_dict(self, _state) -> dict:
        return {}

    def load_state_dict(self, state, sd: dict):
        return state

    def hyperparameters(self) -> dict:
        return {}
