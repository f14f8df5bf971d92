"""Supervised training on true fields: the baseline the seeds compare physics-based rules against.

When the training data carry ``x`` (a scene's own draws, or a file with ``x``), the network can be
fitted to them directly,

    L_x = ½ · mean_i ‖f(y*_i) − x_i‖²        (Euclidean over the unknowns, mean over the batch),

which is SIP's proxy ``½ mean ‖x − x̃‖²`` with the true field in place of the inverse simulator's
``x̃``: the same Gauss–Newton matrix, so the same normalization (:class:`~.sip.SIP`'s ``normalize``:
the network's Gauss–Newton diagonal and largest eigenvalue, measured once). The preset, plain SGD at
lr 1 on the full batch, is then one exact least-squares step on a network linear in its parameters
(the whitened map: the empirical linear MMSE of the training pairs; the prior decoder: its
least-squares fit in the decoder's span). ``x`` reaches the rule as its ``target``
(:class:`pdeinv.methods.targets.TrueFields`, what ``target="auto"`` means for this rule), so it trains
through
the common trainer like every other rule. The physics is not differentiated: it runs forward once per
step (no gradient) for the y-loss every rule reports (:mod:`.base`). A hybrid of a physics rule and
this one is not offered yet.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch

from .base import OptimizerFactory, Update, gradient, prediction, sgd, y_loss
from .sip import SIP, SIPContext


@dataclass(frozen=True)
class Supervised(SIP):
    """Direction ``d⁻¹ ∇_θ L_x / λ̂`` (module docstring), applied by ``optimizer`` (default: SGD, lr 1)."""

    optimizer: OptimizerFactory = field(default_factory=lambda: sgd(1.0))
    name: str = "supervised"
    needs_fields: ClassVar[bool] = True

    def settings(self) -> dict:
        return {"normalize": self.normalize}

    def context(self, problem, model) -> SIPContext:
        return SIPContext(problem.operator, None)

    def default_target(self):
        """What ``target="auto"`` fits for this rule: the training rows' true fields."""
        from .targets import TrueFields

        return TrueFields()

    def update(self, state, model: torch.nn.Module, y_target: torch.Tensor,
               target: torch.Tensor | None = None) -> Update:
        if target is None:
            raise ValueError("Supervised needs the training rows' true fields as its target: keep "
                             "target='auto' (pdeinv.methods.targets.TrueFields) and give data with x")
        op, _, curvature, diagonal, _, _, _ = state.context
        x = prediction(model(y_target))
        if target.shape != x.shape:
            raise ValueError(f"Supervised: the target has shape {tuple(target.shape)}, the network's output "
                             f"{tuple(x.shape)}; the target must be the true fields x")
        loss_x = y_loss(x, target.to(x.dtype))  # ½ mean ‖f(y) − x‖²
        y = np.asarray(op.forward(x.detach().cpu().double().numpy()))
        loss = 0.5 * float(((y - y_target.detach().cpu().double().numpy()) ** 2).sum(-1).mean())
        direction = self.normalized(gradient(loss_x, model), curvature, diagonal)
        return Update(direction, {"loss": loss, "x_loss": float(loss_x.detach())})
