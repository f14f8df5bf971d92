"""Default networks ``f(y; θ) ≈ x``.

The last layer starts at zero: a random head emits components the physics
cannot see (its null space), and no update rule removes them again (DESIGN.md:
x-error near 1.0 against 0.2–0.3 with a zero head on a 961-unknown heat problem).
"""

from __future__ import annotations

import torch
from torch import nn


class MLP(nn.Module):
    """``x = W_L σ(… σ(W_1 (y − μ)/s) …)`` with a zero-initialized last layer.

    ``shift``/``scale`` (μ, s) standardize the input; set them from training data
    with :meth:`fit_input_scaling` (they are buffers, saved with the state dict).
    """

    def __init__(self, n_in: int, n_out: int, hidden=(256, 256), activation=nn.Tanh):
        super().__init__()
        layers, width = [], n_in
        for h in hidden:
            layers += [nn.Linear(width, h), activation()]
            width = h
        head = nn.Linear(width, n_out)
        nn.init.zeros_(head.weight)
        nn.init.zeros_(head.bias)
        self.body = nn.Sequential(*layers, head)
        self.register_buffer("shift", torch.zeros(n_in))
        self.register_buffer("scale", torch.ones(()))

    @torch.no_grad()
    def fit_input_scaling(self, y: torch.Tensor) -> MLP:
        """μ = mean of the training inputs, s = their overall standard deviation."""
        y = torch.as_tensor(y, dtype=self.shift.dtype)
        self.shift.copy_(y.mean(0))
        self.scale.copy_((y - y.mean(0)).std().clamp_min(1e-12))
        return self

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.body((y - self.shift) / self.scale)


def default_model(problem) -> nn.Module:
    """An MLP sized to the problem (observations in, unknowns out)."""
    return MLP(problem.operator.n_out, problem.operator.n_in)


def fit_input_scaling(model: nn.Module, y) -> nn.Module:
    """Set ``model``'s input standardization from training observations ``y``.

    Calls ``model.fit_input_scaling(y)`` if the model has one (e.g. :class:`MLP`);
    other models are left alone (they handle their own input scale).
    """
    fit = getattr(model, "fit_input_scaling", None)
    if callable(fit):
        fit(y)
    return model


def mlp(hidden=(256, 256), activation=nn.Tanh):
    """A ``model_factory`` for :class:`pdeinv.Problem`: ``Problem(..., model_factory=mlp((128, 128)))``.

    The factory receives the problem and sizes the MLP to it (observations in,
    unknowns out).
    """

    def factory(problem) -> nn.Module:
        return MLP(problem.operator.n_out, problem.operator.n_in, hidden=tuple(hidden),
                   activation=activation)

    return factory
