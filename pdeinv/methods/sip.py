"""Scale-invariant physics (SIP) updates: Holl, Koltun & Thuerey, NeurIPS 2022."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from .._checks import positive
from ..physics.base import LinearOperator
from .base import OptimizerFactory, Rule, State, Update, adam, check_finite, gradient, prediction, y_loss
from .transforms import OptimizerStep

#: ``(y_target, x0) -> x̃`` on numpy ``(B, ·)`` arrays: a local inverse ``P⁻¹_(x0, P x0)``
InverseSimulator = Callable[[np.ndarray, np.ndarray], np.ndarray]


class SIPContext(NamedTuple):
    """What SIP needs from the problem, fixed for the run (never checkpointed)."""

    operator: LinearOperator
    inverse: InverseSimulator


@dataclass(frozen=True)
class SIP(Rule):
    """One SIP step (Holl et al. 2022, Alg. 1)::

        x  = f(y*; θ),   y = P(x),   Δy = η (y* − y),
        x̃  = P⁻¹_(x, y)(y + Δy)                      (local inverse simulator, no gradient)
        L̃  = ½ · mean_i ‖x_i − stopgrad(x̃_i)‖²       (Euclidean, mean over the batch)
        direction = ∇_θ L̃,   θ ← optimizer(direction)

    Only the network is differentiated; the physics runs forward once and the
    inverse once, both in float64 numpy. ``inverse`` defaults to the problem's
    own (``problem.inverse(y_target, x0)``), which for linear ``P`` and η = 1 with
    an exact inverse makes ``x̃`` the exact solution. The y-loss reported in
    ``info["loss"]`` is the GD loss at ``x`` (before the update); ``info["proxy"]``
    is ``L̃``. The guard's step-size multiplier scales the optimizer's lr (η stays:
    it sets the target, not the step). The inverse's output is checked (shape,
    finiteness) before it is trained on: it is a user-supplied strategy.
    """

    inverse: InverseSimulator | None = None
    eta: float = 1.0
    optimizer: OptimizerFactory = field(default_factory=adam)
    name: str = "sip"

    def __post_init__(self):
        positive(self.eta, "eta")

    @property
    def transform(self) -> OptimizerStep:
        return OptimizerStep(self.optimizer)

    def settings(self) -> dict:
        inverse = "problem" if self.inverse is None else getattr(self.inverse, "__qualname__",
                                                                  type(self.inverse).__qualname__)
        return {"eta": self.eta, "inverse": inverse}

    def context(self, problem, model) -> SIPContext:
        return SIPContext(problem.operator, self.inverse if self.inverse is not None else problem.inverse)

    def update(self, state: State, model: torch.nn.Module, y_target: torch.Tensor) -> Update:
        op, inverse = state.context
        x = prediction(model(y_target))
        x_np = x.detach().cpu().double().numpy()
        yt = y_target.detach().cpu().double().numpy()
        y = op.forward(x_np)
        loss = 0.5 * float(((y - yt) ** 2).sum(-1).mean())
        if not math.isfinite(loss):  # the inverse is never called on it; the guard refuses
            return Update(None, {"loss": loss})
        x_tilde = np.asarray(inverse(y + self.eta * (yt - y), x_np))
        if x_tilde.shape != x_np.shape:
            raise ValueError(f"the inverse simulator returned shape {x_tilde.shape}; "
                             f"expected {x_np.shape}")
        target = torch.as_tensor(x_tilde, dtype=x.dtype, device=x.device)
        check_finite("the inverse simulator's x̃", target)
        proxy = y_loss(x, target)  # ½ mean ‖x − x̃‖², target carries no gradient
        return Update(gradient(proxy, model), {"loss": loss, "proxy": float(proxy.detach())})
