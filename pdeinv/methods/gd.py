"""Gradient descent through the differentiable simulator (the DP baseline)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from ..autograd import apply
from .base import OptimizerFactory, Rule, State, Update, gradient, prediction, sgd, y_loss
from .transforms import OptimizerStep

#: GD's default learning rate (plain SGD), shared with ``--method gd`` (methods/presets.py)
GD_LR = 0.01


@dataclass(frozen=True)
class GD(Rule):
    """Direction ``∇_θ L`` with ``L = ½ · mean_i ‖P(f(y*_i; θ)) − y*_i‖²``, applied by ``optimizer``.

    The norm is the Euclidean norm of the observation coefficients (as in the
    seeds; reported errors are L²(Ω)); the mean is over the batch. ``∇_θ L`` is
    exact: back-propagation runs through the discrete adjoint ``Pᵀ`` via
    :func:`pdeinv.apply`. ``optimizer`` is a factory ``params -> torch.optim.Optimizer``,
    an optimizer class or an instance (:func:`~.base.make_optimizer`); it is the rule's
    transformation (:class:`~.transforms.OptimizerStep`). The default, plain SGD with lr
    0.01, is what ``pdeinv train --method gd`` runs (:data:`~.presets.GENERIC`; the CLI
    also has per-problem learning rates, :data:`~.presets.PER_PROBLEM`); Adam is
    ``GD(optimizer=pdeinv.adam(1e-3))``, the CLI's ``--method adam``. The context is the
    problem's operator.
    """

    optimizer: OptimizerFactory = field(default_factory=lambda: sgd(GD_LR))
    name: str = "gd"

    @property
    def transform(self) -> OptimizerStep:
        return OptimizerStep(self.optimizer)

    def settings(self) -> dict:
        return {}

    def context(self, problem, model):
        return problem.operator

    def update(self, state: State, model: torch.nn.Module, y_target: torch.Tensor) -> Update:
        loss = y_loss(apply(state.context, prediction(model(y_target))), y_target)
        value = float(loss.detach())
        if not math.isfinite(value):  # no backward through it: the guard refuses the update
            return Update(None, {"loss": value})
        return Update(gradient(loss, model), {"loss": value})
