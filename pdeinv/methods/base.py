"""What every update rule shares: the batch y-loss, finiteness checks, optimizer factories.

An update rule is a small strategy object with explicit state, in the spirit of
optax's ``GradientTransformation``::

    state = rule.init(problem, model)          # rule-specific inputs obtained here
    state, info = rule.step(state, model, y)   # one update of model's parameters in place

``y`` is a batch of target observations ``y*`` (torch, ``(B, n_out)``); ``info``
holds at least ``loss`` — the y-loss of the batch *before* the update,

    L = ½ · mean_i ‖P(f(y*_i)) − y*_i‖²   (Euclidean norm of the coefficient vector),

the same number for every rule, so rules can be compared step by step. A rule
checks its loss and its update for NaN/Inf *before* touching the parameters and
raises :class:`NonFiniteError` (the trainer adds the step number).

Rules whose runs can be checkpointed and guarded against divergence also offer
(see :class:`Resumable`; the trainer asks for them by capability, never by name)::

    sd = rule.state_dict(state)                 # plain dicts / tensors, torch.save-able
    state = rule.load_state_dict(state, sd)     # onto a fresh ``rule.init(...)`` state
    state = rule.scale_step(state, factor)      # multiply the step size (lr or η) by ``factor``
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, Protocol, runtime_checkable

import torch

from ..errors import NonFiniteError  # noqa: F401  (re-exported)

#: ``params -> torch.optim.Optimizer``, e.g. ``functools.partial(torch.optim.Adam, lr=1e-3)``
OptimizerFactory = Callable[[Any], torch.optim.Optimizer]


class UpdateRule(Protocol):
    name: str

    def init(self, problem, model: torch.nn.Module) -> Any: ...

    def step(self, state, model: torch.nn.Module, y: torch.Tensor) -> tuple[Any, dict]: ...


@runtime_checkable
class Resumable(Protocol):
    """A rule whose state can be saved, restored and whose step size can be scaled."""

    def state_dict(self, state) -> dict: ...

    def load_state_dict(self, state, sd: dict) -> Any: ...

    def scale_step(self, state, factor: float) -> Any: ...


class OptimizerState:
    """``state_dict`` / ``load_state_dict`` / ``scale_step`` for rules whose state is a NamedTuple
    with a torch ``optimizer`` and a ``steps`` count (GD, SIP).

    The optimizer's ``state_dict`` holds its moments *and* its param-group
    hyper-parameters, so a step size reduced by :meth:`scale_step` survives a
    checkpoint; restoring it is bitwise.
    """

    def state_dict(self, state) -> dict:
        return {"optimizer": state.optimizer.state_dict(), "steps": state.steps}

    def load_state_dict(self, state, sd: dict):
        state.optimizer.load_state_dict(sd["optimizer"])
        return state._replace(steps=int(sd["steps"]))

    def scale_step(self, state, factor: float):
        for group in state.optimizer.param_groups:
            group["lr"] = group["lr"] * factor
        return state


def adam(lr: float = 1e-3, **kw) -> OptimizerFactory:
    return partial(torch.optim.Adam, lr=lr, **kw)


def sgd(lr: float = 1e-2, **kw) -> OptimizerFactory:
    return partial(torch.optim.SGD, lr=lr, **kw)


def make_optimizer(factory: OptimizerFactory, model: torch.nn.Module) -> torch.optim.Optimizer:
    params = [p for p in model.parameters() if p.requires_grad]
    if not params:
        raise ValueError("the model has no trainable parameters")
    opt = factory(params)
    if not isinstance(opt, torch.optim.Optimizer):
        raise ValueError(f"optimizer factory returned {type(opt).__name__}; "
                         "expected a torch.optim.Optimizer (e.g. partial(torch.optim.Adam, lr=1e-3))")
    return opt


def check_finite(name: str, value: torch.Tensor) -> None:
    """Raise :class:`NonFiniteError` if ``value`` holds NaN or Inf."""
    if not bool(torch.isfinite(value).all()):
        raise NonFiniteError(f"{name} is not finite ({_describe(value)}); the update was not applied "
                             "(lower the learning rate / eta, or raise tau for HIG)")


def check_grads(model: torch.nn.Module, what: str) -> None:
    for name, p in model.named_parameters():
        if p.grad is not None and not bool(torch.isfinite(p.grad).all()):
            raise NonFiniteError(f"gradient of {what} w.r.t. {name!r} is not finite "
                                 f"({_describe(p.grad)}); the update was not applied")


def _describe(t: torch.Tensor) -> str:
    t = t.detach()
    return f"{int(torch.isnan(t).sum())} NaN, {int(torch.isinf(t).sum())} Inf of {t.numel()}"


def y_loss(y: torch.Tensor, y_target: torch.Tensor) -> torch.Tensor:
    """``½ · mean_i ‖y_i − y*_i‖²`` (Euclidean, mean over the batch)."""
    return 0.5 * (y - y_target).pow(2).sum(-1).mean()


def optimizer_step(optimizer: torch.optim.Optimizer, model, loss: torch.Tensor, what: str) -> None:
    """Back-propagate ``loss``, check it and the gradients, step the optimizer."""
    check_finite(what, loss.detach())
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    check_grads(model, what)
    optimizer.step()
