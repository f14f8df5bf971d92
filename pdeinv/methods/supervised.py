"""Supervised training on true fields: the baseline the seeds compare physics-based rules against.

When the training data carry ``x`` (a scene's own draws, or a file with ``x``), the network can be
fitted to them directly,

    L_x = ½ · mean_i ‖f(y*_i) − x_i‖²        (Euclidean over the unknowns, mean over the batch),

with any torch optimizer; ``x`` reaches the rule as its ``target`` (:class:`pdeinv.targets.TrueFields`,
what ``target="auto"`` means for this rule), so it trains through the common trainer like every other
rule. The physics is not differentiated: it runs forward once per step (no gradient) for the y-loss
every rule reports (:mod:`.base`). A hybrid of a physics rule and this one is not offered yet.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from .base import OptimizerFactory, Rule, Update, adam, gradient, prediction
from .transforms import OptimizerStep


@dataclass(frozen=True)
class Supervised(Rule):
    """Direction ``∇_θ L_x`` (module docstring), applied by ``optimizer`` (default Adam 1e-3)."""

    optimizer: OptimizerFactory = field(default_factory=lambda: adam(1e-3))
    name: str = "supervised"

    @property
    def transform(self) -> OptimizerStep:
        return OptimizerStep(self.optimizer)

    def settings(self) -> dict:
        return {}

    def context(self, problem, model):
        return problem.operator

    def default_target(self):
        """What ``target="auto"`` fits for this rule: the training rows' true fields."""
        from ..targets import TrueFields

        return TrueFields()

    def update(self, state, model: torch.nn.Module, y_target: torch.Tensor,
               target: torch.Tensor | None = None) -> Update:
        if target is None:
            raise ValueError("Supervised needs the training rows' true fields as its target: keep "
                             "target='auto' (pdeinv.targets.TrueFields) and give data with x")
        x = prediction(model(y_target))
        if target.shape != x.shape:
            raise ValueError(f"Supervised: the target has shape {tuple(target.shape)}, the network's output "
                             f"{tuple(x.shape)}; the target must be the true fields x")
        loss_x = 0.5 * (x - target.to(x.dtype)).pow(2).sum(-1).mean()
        y = np.asarray(state.context.forward(x.detach().cpu().double().numpy()))
        loss = 0.5 * float(((y - y_target.detach().cpu().double().numpy()) ** 2).sum(-1).mean())
        return Update(gradient(loss_x, model), {"loss": loss, "x_loss": float(loss_x.detach())})
