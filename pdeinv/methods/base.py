"""What every update rule shares: the update it returns, its state, the batch y-loss, optimizer factories.

An update rule is a small strategy object in the spirit of optax's
``GradientTransformation``: it *computes* an update and never touches the
parameters; applying it is someone else's job (:mod:`.guard`, the trainer)::

    state = rule.init(problem, model)          # State(context, transform, steps)
    update = rule.update(state, model, y)      # Update(direction, info): parameters untouched
    rule.transform                             # how a direction becomes a parameter change

``y`` is a batch of target observations ``y*`` (torch, ``(B, n_out)``), the network's input; an
optional ``target`` (same shape) is what ``P f(y*)`` must match instead of ``y*`` (a denoised
``y*``, :mod:`pdeinv.methods.targets`; the trainer passes it only when it has one);
``update.direction`` holds one tensor per trainable parameter (in
``model.parameters()`` order, ``None`` for one the rule leaves alone) and
``update.info`` at least ``loss`` — the y-loss of the batch *before* the update,

    L = ½ · mean_i ‖P(f(y*_i)) − y*_i‖²   (Euclidean norm of the coefficient vector),

the same number for every rule, so rules can be compared step by step. A rule
whose loss is not finite may stop early and return ``direction=None``.

The :class:`State` separates what a run must save (the transformation's state,
e.g. a torch optimizer's moments, and the count of accepted steps) from the
static ``context`` built once from the problem (operator, inverse simulator),
which is rebuilt by ``init`` and never saved. Checking the update for NaN/Inf
and applying it with the run's step-size multiplier is :func:`.guard.apply_if_finite`,
the one place that does it for every rule; :mod:`.guard` imports nothing from here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, ClassVar, NamedTuple, Protocol

import torch

from .._checks import positive
from ..errors import NonFiniteError  # noqa: F401  (re-exported)
from ..util.files import plain
from . import guard
from .guard import describe, finite, trainable  # noqa: F401  (re-exported)

#: ``params -> torch.optim.Optimizer``, e.g. ``functools.partial(torch.optim.Adam, lr=1e-3)``
OptimizerFactory = Callable[[Any], torch.optim.Optimizer]


class Update(NamedTuple):
    """What a rule proposes: a direction per trainable parameter (``None``: none) and what it measured."""

    direction: tuple[torch.Tensor | None, ...] | None
    info: dict


class State(NamedTuple):
    """A rule's state: ``context`` is static (never saved), ``transform`` and ``steps`` are resumable."""

    context: Any
    transform: Any = None
    steps: int = 0


class UpdateRule(Protocol):
    name: str
    transform: Any  # a transformation (pdeinv.methods.transforms): direction -> parameter change

    def init(self, problem, model: torch.nn.Module) -> State: ...

    def update(self, state: State, model: torch.nn.Module, y: torch.Tensor,
               target: torch.Tensor | None = None) -> Update: ...


class Resumable(Protocol):
    """A rule whose run can be checkpointed (declared by ``resumable = True``, :mod:`.protocol`): its
    state saved and restored, and every hyper-parameter a resumed run must share named."""

    resumable: bool

    def state_dict(self, state) -> dict: ...

    def load_state_dict(self, state, sd: dict) -> Any: ...

    def hyperparameters(self) -> dict: ...


def adam(lr: float = 1e-3, **kw) -> OptimizerFactory:
    """``params -> torch.optim.Adam(params, lr=lr, **kw)``; ``lr`` a finite number > 0 and ``kw`` what
    Adam takes (checked here, not at the first step)."""
    return _checked(torch.optim.Adam, "adam", lr=positive(_scalar(lr), "adam lr"), **kw)


def sgd(lr: float = 1e-2, **kw) -> OptimizerFactory:
    """``params -> torch.optim.SGD(params, lr=lr, **kw)``; ``lr`` a finite number > 0 and ``kw`` what SGD
    takes (checked here, not at the first step)."""
    return _checked(torch.optim.SGD, "sgd", lr=positive(_scalar(lr), "sgd lr"), **kw)


def _scalar(value):
    """A 0-d tensor as its number (``lr=torch.tensor(1e-3)``); anything else as it is."""
    return value.item() if isinstance(value, torch.Tensor) and value.ndim == 0 else value


#: torch.optim's switches: True or False (``foreach`` and ``fused`` also None, torch's choice)
FLAGS = {"amsgrad", "maximize", "foreach", "capturable", "differentiable", "fused", "nesterov",
         "decoupled_weight_decay"}


def _checked(cls, name: str, **settings) -> OptimizerFactory:
    """``partial(cls, **settings)`` once ``cls`` has accepted ``settings`` on one scalar parameter: torch
    checks ``betas``, ``weight_decay``, ``momentum`` … only when the optimizer is built, at the first step of
    a run; here a bad one is a ``ValueError`` naming the call and the setting."""
    shown = ", ".join(f"{k}={v!r}" for k, v in settings.items() if k != "lr")
    for k in FLAGS & set(settings):
        if not isinstance(settings[k], bool) and not (settings[k] is None and k in ("foreach", "fused")):
            # amsgrad='yes' would be taken as True
            raise ValueError(f"pdeinv.{name}({shown}) is not allowed: {k}={settings[k]!r} is not True or "
                             "False")
    try:
        cls([torch.zeros(1, requires_grad=True)], **settings)
    except (ValueError, TypeError, IndexError) as err:  # IndexError: betas=(0.9,), which torch indexes
        err = f"{type(err).__name__}: {err}" if isinstance(err, IndexError) else err
        raise ValueError(f"pdeinv.{name}({shown}) is not allowed: {err}; expected the settings of "
                         f"torch.optim.{cls.__name__}") from None
    return partial(cls, **settings)


def make_optimizer(factory, params: list) -> torch.optim.Optimizer:
    """A fresh optimizer on ``params`` from any of three equivalent specs:

    * a factory ``params -> Optimizer`` (``pdeinv.adam(1e-3)``, ``partial(torch.optim.Adam, lr=1e-3)``);
    * an optimizer class (``torch.optim.Adam``: its own defaults);
    * an optimizer instance (``torch.optim.Adam(model.parameters(), lr=1e-3)``): its class and
      settings (``defaults``) are reused on ``params``, its state is not.
    """
    if not params:
        raise ValueError("the model has no trainable parameters")
    if isinstance(factory, torch.optim.Optimizer):
        cls, settings = type(factory), dict(factory.defaults)
        factory = lambda ps: cls(ps, **settings)  # noqa: E731
    try:
        opt = factory(params)
    except TypeError as err:
        raise ValueError(f"optimizer {factory!r} could not be built on the parameters ({err}); expected "
                         "a factory (pdeinv.adam(1e-3)), a torch.optim class or instance") from None
    if not isinstance(opt, torch.optim.Optimizer):
        raise ValueError(f"optimizer factory returned {type(opt).__name__}; "
                         "expected a torch.optim.Optimizer (e.g. partial(torch.optim.Adam, lr=1e-3))")
    if isinstance(opt, torch.optim.LBFGS):  # its step re-evaluates the loss through a closure
        raise ValueError("optimizer LBFGS is not allowed: its step needs a closure that re-evaluates the "
                         "loss (a line search), and a rule takes one step per batch; expected a first-order "
                         "optimizer (pdeinv.adam(lr), pdeinv.sgd(lr), torch.optim.AdamW, ...)")
    given = {id(p) for p in params}
    held = {id(p) for group in opt.param_groups for p in group["params"]}
    if not held & given or held - given:  # it would step tensors the model does not have: trains nothing
        raise ValueError(f"optimizer {factory!r} built a {type(opt).__name__} over {len(held - given)} "
                         f"tensors not among the parameters it was given ({len(given)} of the model); "
                         "expected a "
                         "factory of the parameters it gets: params -> torch.optim.SGD(params, lr=…) "
                         "(pdeinv.sgd(lr), pdeinv.adam(lr))")
    return opt


@dataclass(frozen=True)
class WithLR:
    """``factory``'s optimizer at learning rate ``lr`` in every parameter group (a rule's ``lr=``: the
    CLI's ``--lr``)."""

    factory: OptimizerFactory
    lr: float

    def __call__(self, params: list) -> torch.optim.Optimizer:
        opt = make_optimizer(self.factory, params)
        opt.defaults["lr"] = self.lr
        for group in opt.param_groups:
            group["lr"] = self.lr
        return opt


def at_lr(factory: OptimizerFactory, lr: float | None) -> OptimizerFactory:
    """``factory`` (``lr`` None) or :class:`WithLR` (``lr`` a finite number > 0, checked here); ``factory``
    is one of :func:`make_optimizer`'s three specs (anything else, ``'adam'`` or ``None``, was accepted by
    the rule and failed at its first step, or never)."""
    if not (callable(factory) or isinstance(factory, torch.optim.Optimizer)):
        raise TypeError(f"optimizer={factory!r} is {type(factory).__name__}; expected a factory params -> "
                        "torch.optim.Optimizer (pdeinv.adam(1e-3), pdeinv.sgd(0.1)), an optimizer class or "
                        "an optimizer")
    return factory if lr is None else WithLR(factory, positive(lr, "lr"))


def optimizer_hyperparameters(factory: OptimizerFactory) -> dict:
    """``{"optimizer": class name, **defaults}`` of what ``factory`` builds: lr, betas, momentum, …

    Read from an optimizer built on a dummy parameter, so every setting counts, the
    factory's defaults included (not only the keywords it was given).
    """
    opt = make_optimizer(factory, [torch.nn.Parameter(torch.zeros(1))])
    return {"optimizer": type(opt).__name__, **plain(opt.defaults)}


def check_finite(name: str, value: torch.Tensor) -> None:
    """Raise :class:`NonFiniteError` if ``value`` holds NaN or Inf (a rule naming its culprit)."""
    if not finite(value):
        raise NonFiniteError(f"{name} is not finite ({describe(value)}); the update was not applied "
                             "(lower the learning rate / eta, or raise tau for HIG)")


def prediction(x: torch.Tensor) -> torch.Tensor:
    """``x = f(y*)``, refused (:class:`NonFiniteError`) when not finite: the physics refuses NaN input."""
    check_finite("the network output x = f(y*)", x.detach())
    return x


def y_loss(y: torch.Tensor, y_target: torch.Tensor) -> torch.Tensor:
    """``½ · mean_i ‖y_i − y*_i‖²`` (Euclidean, mean over the batch)."""
    return 0.5 * (y - y_target).pow(2).sum(-1).mean()


def gradient(loss: torch.Tensor, model: torch.nn.Module) -> tuple[torch.Tensor | None, ...]:
    """``∇_θ loss`` per trainable parameter (``None`` where the loss does not depend on it)."""
    return torch.autograd.grad(loss, trainable(model), allow_unused=True)


class Rule:
    """``init``, one-off ``step``, ``state_dict`` / ``load_state_dict`` and ``hyperparameters`` for
    rules that define ``context(problem, model)``, ``update``, ``transform`` and ``settings()``; and the
    declarations the trainer asks (:mod:`.protocol`), here with their defaults."""

    #: ``update`` takes ``target=`` (what ``P f(y)`` must match instead of ``y``)
    accepts_target: ClassVar[bool] = True
    #: ``state_dict`` / ``load_state_dict`` / ``hyperparameters`` restore a run
    resumable: ClassVar[bool] = True
    #: it fits the rows' true fields ``x`` (no fresh draws, whose ``x`` no loss sees)
    needs_fields: ClassVar[bool] = False

    def default_target(self):
        """The target strategy ``target="auto"`` means for this rule; ``None``: the trainer's default
        (:class:`~pdeinv.methods.targets.SpectralWiener`)."""
        return None

    def data_parallel(self, sum_over: Callable, processes: int) -> Rule | None:
        """The rule to run on each of ``processes`` data-parallel ranks (``sum_over`` sums numpy arrays
        over them), whose directions the ranks then average; ``None``: it cannot run so. Default:
        itself, for a direction that is a mean over the batch's rows (GD, Adam, SIP); HIG overrides."""
        return self

    def init(self, problem, model: torch.nn.Module) -> State:
        return State(self.context(problem, model), self.transform.init(trainable(model)))

    def calibrate(self, state: State, model: torch.nn.Module, y: torch.Tensor) -> State:
        """Measure what the rule needs from data once, on the run's first batch ``y`` (before the first
        step; e.g. SIP's proxy curvature). Default: nothing."""
        return state

    def step(self, state: State, model: torch.nn.Module, y: torch.Tensor):
        """One guarded update, applied at full step size: ``(state, info)`` (for one-off use;
        :func:`.guard.step`)."""
        return guard.step(self, state, model, y)

    def state_dict(self, state: State) -> dict:
        """The resumable part (plain dicts / tensors, ``torch.save``-able); the context is not saved."""
        return {"transform": self.transform.state_dict(state.transform), "steps": state.steps}

    def load_state_dict(self, state: State, sd: dict) -> State:
        """``sd`` onto a fresh ``init`` state (bitwise: a torch optimizer's own ``load_state_dict``)."""
        return state._replace(transform=self.transform.load_state_dict(state.transform, sd["transform"]),
                              steps=int(sd["steps"]))

    def hyperparameters(self) -> dict:
        """Every setting a resumed run must share: the rule's own and its transformation's."""
        return {**plain(self.settings()), **self.transform.hyperparameters()}
