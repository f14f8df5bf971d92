"""Gradient descent through the differentiable simulator (the DP baseline)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .._checks import flag, label
from ..physics.bridge import apply
from .base import OptimizerFactory, Rule, State, Update, at_lr, gradient, prediction, sgd, y_loss
from .curvature import checked, gauss_newton_max, operator_norm2
from .transforms import OptimizerStep

#: GD's default learning rate (plain SGD on the normalized gradient: the stable step 1/λ_max), shared
#: with ``--method gd`` (methods/presets.py)
GD_LR = 1.0


@dataclass(frozen=True)
class GD(Rule):
    """Direction ``∇_θ L`` with ``L = ½ · mean_i ‖P(f(y*_i; θ)) − y*_i‖²``, applied by ``optimizer``.

    The norm is the Euclidean norm of the observation coefficients (as in the
    seeds; reported errors are L²(Ω)); the mean is over the batch. ``∇_θ L`` is
    exact: back-propagation runs through the discrete adjoint ``Pᵀ`` via
    :func:`pdeinv.apply`. ``optimizer`` is a factory ``params -> torch.optim.Optimizer``,
    an optimizer class or an instance (:func:`~.base.make_optimizer`); it is the rule's
    transformation (:class:`~.transforms.OptimizerStep`). The default, plain SGD with lr
    1 on the normalized gradient, is what ``pdeinv train --method gd`` runs
    (:data:`~.presets.GENERIC`); Adam is ``GD(optimizer=pdeinv.adam(1e-3))``, the CLI's
    ``--method adam`` (scale-invariant: the normalization changes nothing but its ε). The context
    is the problem's operator and the curvature.

    ``lr`` sets the optimizer's learning rate (``GD(lr=0.5)``: ``--method gd --lr 0.5``; ``None``: its
    own). ``normalize=True`` (default) divides the gradient by ``λ̂ = λ_max(PᵀP) · λ_max((1/B) JᵀJ)`` on
    the run's first batch (:mod:`.curvature`: the loss's largest curvature for a network linear in
    θ, an upper bound otherwise), set by :meth:`calibrate` and saved with the state: plain SGD's lr
    is then in units of the stable step ``1/λ_max`` (lr 1 is stable whatever the physics' scale and
    the network's input scale), which is what ``pdeinv train --method gd`` runs.
    """

    optimizer: OptimizerFactory = field(default_factory=lambda: sgd(GD_LR))
    normalize: bool = True
    name: str = "gd"
    lr: float | None = None  # the optimizer's learning rate (the CLI's --lr); None: the optimizer's own

    def __post_init__(self):
        label(self.name, "name")
        flag(self.normalize, "normalize")
        at_lr(self.optimizer, self.lr)  # checks lr

    @property
    def transform(self) -> OptimizerStep:
        return OptimizerStep(at_lr(self.optimizer, self.lr))

    def settings(self) -> dict:
        return {"normalize": self.normalize}

    def context(self, problem, model):
        return (problem.operator, None)

    def calibrate(self, state: State, model: torch.nn.Module, y: torch.Tensor) -> State:
        """``λ̂`` on the batch ``y`` (when ``normalize``): called once, before the first step."""
        op, lam = state.context
        if not self.normalize or lam is not None:
            return state
        lam = checked(operator_norm2(op) * gauss_newton_max(model, y),
                      "GD(normalize=True): the loss's curvature")
        return state._replace(context=(op, lam))

    def state_dict(self, state: State) -> dict:
        return {**super().state_dict(state), "curvature": state.context[1]}

    def load_state_dict(self, state: State, sd: dict) -> State:
        state = super().load_state_dict(state, sd)
        return state._replace(context=(state.context[0], sd.get("curvature")))

    def update(self, state: State, model: torch.nn.Module, y_target: torch.Tensor,
               target: torch.Tensor | None = None) -> Update:
        op, lam = state.context
        if self.normalize and lam is None:
            raise ValueError("GD(normalize=True) needs its curvature: call state = rule.calibrate(state, "
                             "model, y) on a first batch (pdeinv.Trainer and rule.step do)")
        goal = y_target if target is None else target  # what P f(y*) must match (pdeinv.methods.targets)
        loss = y_loss(apply(op, prediction(model(y_target))), goal)
        value = float(loss.detach())
        if not math.isfinite(value):  # no backward through it: the guard refuses the update
            return Update(None, {"loss": value})
        direction = gradient(loss, model)
        if self.normalize:
            direction = tuple(None if d is None else d / lam for d in direction)
        return Update(direction, {"loss": value})
