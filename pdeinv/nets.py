"""Default networks ``f(y; θ) ≈ x``.

The last layer starts at zero: a random head emits components the physics
cannot see (its null space), and no update rule removes them again (DESIGN.md:
x-error near 1.0 against 0.2–0.3 with a zero head on a 961-unknown heat problem).
"""

from __future__ import annotations

import torch
from torch import nn

from .precondition import REL_FLOOR, Whitening


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

    def fit_observations(self, y, noise: float | None = None) -> MLP:
        """The preconditioning hook (:func:`fit_preconditioning`): per-node standardization."""
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
    """``W_L σ(… σ(W_1 z) …)`` with a zero-initialized last layer (no input scaling)."""
    layers, width = [], n_in
    for h in hidden:
        layers += [nn.Linear(width, h), activation()]
        width = h
    head = nn.Linear(width, n_out)
    nn.init.zeros_(head.weight)
    nn.init.zeros_(head.bias)
    return nn.Sequential(*layers, head)


class Residual(nn.Module):
    """``x = A z + b + g(z)``: a linear path plus a dense correction ``g``, both heads starting at zero."""

    def __init__(self, n_in: int, n_out: int, hidden=(256, 256), activation=nn.Tanh):
        super().__init__()
        self.linear = dense(n_in, n_out, ())
        self.correction = dense(n_in, n_out, hidden, activation)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.linear(z) + self.correction(z)


class Net(nn.Module):
    """``x = body(pre(y))``: a fitted input transform ``pre`` (e.g. :class:`~pdeinv.precondition.Whitening`)
    and a trainable ``body``. :meth:`fit_observations` fits ``pre`` on training observations."""

    def __init__(self, pre: nn.Module, body: nn.Module):
        super().__init__()
        self.pre, self.body = pre, body

    def fit_observations(self, y, noise: float | None = None) -> Net:
        fit = getattr(self.pre, "fit_observations", None)
        if callable(fit):
            fit(y, noise)
        return self

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.body(self.pre(y))


def default_model(problem) -> nn.Module:
    """The problem's default network (:data:`PRESETS`, chosen by measurement)."""
    return whitened("linear")(problem)


def fit_preconditioning(model: nn.Module, y, noise: float | None = None) -> nn.Module:
    """Fit ``model``'s input transform on training observations ``y`` (never on ``x``).

    Calls ``model.fit_observations(y, noise)`` if the model has one (:class:`Net`,
    :class:`MLP`); ``noise`` is the relative noise level when known (it sets the
    whitening floor). Other models are left alone.
    """
    fit = getattr(model, "fit_observations", None)
    if callable(fit):
        fit(y, noise)
    return model


#: bodies of the whitened networks: name -> (n_in, n_out, hidden, activation) -> module
BODIES = {
    "linear": lambda n_in, n_out, hidden, act: dense(n_in, n_out, ()),
    "mlp": dense,
    "residual": Residual,
}


def whitened(body: str = "linear", hidden=(256, 256), activation=nn.Tanh, rel_floor: float = REL_FLOOR,
             drop: float | str = "edge"):
    """A ``model_factory``: :class:`Net` of a :class:`Whitening` and a body from :data:`BODIES`."""
    if body not in BODIES:
        raise ValueError(f"body={body!r} is not allowed; expected one of {', '.join(map(repr, BODIES))}")

    def factory(problem) -> nn.Module:
        m, n = problem.operator.n_out, problem.operator.n_in
        return Net(Whitening(m, rel_floor, drop), BODIES[body](m, n, tuple(hidden), activation))

    return factory


def mlp(hidden=(256, 256), activation=nn.Tanh):
    """A ``model_factory`` for :class:`pdeinv.Problem`: ``Problem(..., model_factory=mlp((128, 128)))``.

    The factory receives the problem and sizes the MLP to it (observations in,
    unknowns out).
    """

    def factory(problem) -> nn.Module:
        return MLP(problem.operator.n_out, problem.operator.n_in, hidden=tuple(hidden),
                   activation=activation)

    return factory
