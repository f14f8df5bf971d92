"""Gradient descent through the differentiable simulator (the DP baseline)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import torch

from ..autograd import apply
from ..physics.base import LinearOperator
from .base import (
    OptimizerFactory,
    OptimizerState,
    adam,
    check_finite,
    make_optimizer,
    optimizer_step,
    y_loss,
)


class GDState(NamedTuple):
    optimizer: torch.optim.Optimizer
    operator: LinearOperator
    steps: int = 0


@dataclass(frozen=True)
class GD(OptimizerState):
    """``θ ← optimizer(∇_θ L)`` with ``L = ½ · mean_i ‖P(f(y*_i; θ)) − y*_i‖²``.

    The norm is the Euclidean norm of the observation coefficients (as in the
    seeds; reported errors are L²(Ω)); the mean is over the batch. ``∇_θ L`` is
    exact: back-propagation runs through the discrete adjoint ``Pᵀ`` via
    :func:`pdeinv.apply`. ``optimizer`` is any ``params -> torch.optim.Optimizer``
    (default Adam with lr 1e-3; ``methods.sgd(lr)`` gives textbook GD).
    ``scale_step`` multiplies the optimizer's lr; ``state_dict`` is the optimizer's.
    """

    optimizer: OptimizerFactory = field(default_factory=adam)
    name: str = "gd"

    def init(self, problem, model: torch.nn.Module) -> GDState:
        return GDState(make_optimizer(self.optimizer, model), problem.operator)

    def step(self, state: GDState, model: torch.nn.Module, y_target: torch.Tensor):
        x = model(y_target)
        check_finite("the network output x = f(y*)", x.detach())
        loss = y_loss(apply(state.operator, x), y_target)
        optimizer_step(state.optimizer, model, loss, "the y-loss")
        return state._replace(steps=state.steps + 1), {"loss": float(loss.detach())}
