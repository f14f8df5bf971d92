"""Plain networks: a tanh :class:`MLP` on per-node standardized input (what ``--method adam`` trains), dense
stacks (:func:`dense`), the zero head every network starts from (:func:`zero_last_layer`) and a linear path
plus a dense correction (:class:`Residual`)."""

from __future__ import annotations

import torch
from torch import nn

from .._checks import activation_class, count, shown, widths
from .._checks import problem as _problem
from .protocol import Network


class MLP(Network):
    """``x = W_L σ(… σ(W_1 (y − μ)/s) …)`` with a zero-initialized last layer.

    ``shift``/``scale`` (μ, s) standardize the input; set them from training data
    with :meth:`fit_input_scaling` (they are buffers, saved with the state dict).
    """

    def __init__(self, n_in: int, n_out: int, hidden=(256, 256), activation=nn.Tanh):
        super().__init__()
        self.body = dense(n_in, n_out, hidden, activation)  # checks the arguments
        self.register_buffer("shift", torch.zeros(int(n_in)))
        self.register_buffer("scale", torch.ones(()))

    def fit_observations(self, y, noise: float | None = None, **settings) -> MLP:
        """The preconditioning hook (:func:`fit_preconditioning`): per-node standardization (the
        whitening's ``settings`` do not apply)."""
        return self.fit_input_scaling(y)

    @torch.no_grad()
    def fit_input_scaling(self, y: torch.Tensor) -> MLP:
        """μ = mean of the training inputs, s = their overall standard deviation."""
        y = torch.as_tensor(y, dtype=self.shift.dtype)
        self.shift.copy_(y.mean(0))
        self.scale.copy_((y - y.mean(0)).std().clamp_min(1e-12))
        return self

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.body((y - self.shift) / self.scale)


def dense(n_in: int, n_out: int, hidden=(256, 256), activation=nn.Tanh) -> nn.Sequential:
    """``W_L σ(… σ(W_1 z) …)`` with a zero-initialized last layer (no input scaling). ``n_in``, ``n_out``:
    integers >= 1; ``hidden``: integer widths >= 1 (``()``: one linear layer); ``activation``: an
    ``nn.Module`` class."""
    n_in, n_out = count(n_in, "n_in"), count(n_out, "n_out")
    hidden, activation = widths(hidden), activation_class(activation)
    layers, width = [], n_in
    for h in hidden:
        layers += [nn.Linear(width, h), activation()]
        width = h
    return zero_last_layer(nn.Sequential(*layers, nn.Linear(width, n_out)))


@torch.no_grad()
def zero_last_layer(model: nn.Module) -> nn.Module:
    """Set the weight and bias of ``model``'s last ``nn.Linear`` (in ``modules()`` order) to zero;
    returns ``model``.

    Do this to a network of your own: a random head emits components the physics cannot
    see, and no update rule removes them. ``ValueError`` if the model has no ``nn.Linear``.
    """
    if not isinstance(model, nn.Module):
        raise TypeError(f"model={shown(model)} is {type(model).__name__}; expected a torch.nn.Module")
    linears = [m for m in model.modules() if isinstance(m, nn.Linear)]
    if not linears:
        raise ValueError(f"zero_last_layer: {type(model).__name__} has no torch.nn.Linear layer; "
                         "zero its output layer's weight and bias yourself")
    nn.init.zeros_(linears[-1].weight)
    if linears[-1].bias is not None:
        nn.init.zeros_(linears[-1].bias)
    return model


class Residual(nn.Module):
    """``x = A z + b + g(z)``: a linear path plus a dense correction ``g``, both heads starting at zero."""

    def __init__(self, n_in: int, n_out: int, hidden=(256, 256), activation=nn.Tanh):
        super().__init__()
        self.linear = dense(n_in, n_out, ())
        self.correction = dense(n_in, n_out, hidden, activation)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.linear(z) + self.correction(z)


def mlp(hidden=(256, 256), activation=nn.Tanh):
    """A ``model_factory`` for :class:`pdeinv.Problem`: ``Problem(..., model_factory=mlp((128, 128)))``.

    The factory receives the problem and sizes the MLP to it (observations in,
    unknowns out).
    ``hidden``: the widths of the hidden layers (integers >= 1); ``activation``: an ``nn.Module`` class
    (called once per hidden layer).
    """
    hidden, activation = widths(hidden), activation_class(activation)

    def factory(problem) -> nn.Module:
        problem = _problem(problem)
        return MLP(problem.operator.n_out, problem.operator.n_in, hidden=hidden, activation=activation)

    return factory
