"""Scale-invariant physics (SIP) updates: Holl, Koltun & Thuerey, NeurIPS 2022."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from .._checks import positive
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

#: ``(y_target, x0) -> x̃`` on numpy ``(B, ·)`` arrays: a local inverse ``P⁻¹_(x0, P x0)``
InverseSimulator = Callable[[np.ndarray, np.ndarray], np.ndarray]


class SIPState(NamedTuple):
    optimizer: torch.optim.Optimizer
    operator: LinearOperator
    inverse: InverseSimulator
    steps: int = 0


@dataclass(frozen=True)
class SIP(OptimizerState):
    """One SIP step (Holl et al. 2022, Alg. 1)::

        x  = f(y*; θ),   y = P(x),   Δy = η (y* − y),
        x̃  = P⁻¹_(x, y)(y + Δy)                      (local inverse simulator, no gradient)
        L̃  = ½ · mean_i ‖x_i − stopgrad(x̃_i)‖²       (Euclidean, mean over the batch)
        θ  ← optimizer(∇_θ L̃)

    Only the network is differentiated; the physics runs forward once and the
    inverse once, both in float64 numpy. ``inverse`` defaults to the problem's
    own (``problem.inverse(y_target, x0)``), which for linear ``P`` and η = 1 with
    an exact inverse makes ``x̃`` the exact solution. The y-loss reported in
    ``info["loss"]`` is the GD loss at ``x`` (before the update); ``info["proxy"]``
    is ``L̃``. ``scale_step`` multiplies the optimizer's lr (η stays: it sets the
    target, not the step); ``state_dict`` is the optimizer's.
    """

    inverse: InverseSimulator | None = None
    eta: float = 1.0
    optimizer: OptimizerFactory = field(default_factory=adam)
    name: str = "sip"

    def __post_init__(self):
        positive(self.eta, "eta")

    def init(self, problem, model: torch.nn.Module) -> SIPState:
        inverse = self.inverse if self.inverse is not None else problem.inverse
        return SIPState(make_optimizer(self.optimizer, model), problem.operator, inverse)

    def step(self, state: SIPState, model: torch.nn.Module, y_target: torch.Tensor):
        x = model(y_target)
        check_finite("the network output x = f(y*)", x.detach())
        x_np = x.detach().cpu().double().numpy()
        yt = y_target.detach().cpu().double().numpy()
        y = state.operator.forward(x_np)
        loss = 0.5 * float(((y - yt) ** 2).sum(-1).mean())
        if not np.isfinite(loss):
            check_finite("the y-loss", torch.tensor(loss))
        x_tilde = np.asarray(state.inverse(y + self.eta * (yt - y), x_np))
        if x_tilde.shape != x_np.shape:
            raise ValueError(f"the inverse simulator returned shape {x_tilde.shape}; "
                             f"expected {x_np.shape}")
        target = torch.as_tensor(x_tilde, dtype=x.dtype, device=x.device)
        check_finite("the inverse simulator's x̃", target)
        proxy = y_loss(x, target)  # ½ mean ‖x − x̃‖², target carries no gradient
        optimizer_step(state.optimizer, model, proxy, "the SIP proxy loss")
        return state._replace(steps=state.steps + 1), {"loss": loss, "proxy": float(proxy.detach())}
