"""The guard: one object around any rule (optax's ``apply_if_finite``) that owns the step-size multiplier,
the failure count, the lowest loss, the last good state and the roll-back.

:func:`apply_if_finite` asks the rule for its update, checks it, and only then lets the rule's
transformation apply it with the step-size multiplier ``scale``. It *rejects* (raises
:class:`~pdeinv.errors.NonFiniteError`, nothing applied):

* a non-finite loss or direction (NaN/Inf);
* a finite loss above ``max_loss`` (:class:`Diverged`): the :class:`Guard` passes ``max_loss_growth``
  (default 1e3) times the lowest accepted loss so far. A loss is measured *before* its update, so a
  huge loss says the previous update blew up;
* a nonlinear solve of the physics that did not converge at the network's output
  (:class:`~pdeinv.errors.ConvergenceError`, e.g. Newton on allen_cahn_1d after a HIG step that sent
  the output far out): also :class:`Diverged`, for the same reason.

**Last good state.** The loss of step k is that of the parameters left by step k − 1: once it passes,
those parameters are known to be good. Every ``snapshot_every`` accepted steps (10) a :class:`Snapshot`
copies them and the rule's state (optimizer moments, step count) before step k's update is applied.
On a rejection the guard restores it, undoing the update that blew up and the at most
``snapshot_every − 1`` good steps after the snapshot (they are redone, at the lowered step size). The
copy goes into buffers allocated once (``copy_``, no allocation: the update is in place, so the
pre-update values must be copied, but never deep-copied), and is exact, so a checkpoint holding it
resumes bitwise. Copying every step cost 4.6 ms of a 45 ms Adam step on heat_2d's default network
(θ and Adam's two moments, 3 × 7.4 MB): every 10th step it costs a tenth of that
(``benchmarks/overhead.py``). ``snapshot_every=1`` gives the exact one-step roll-back. Finiteness is
tested with one sum per tensor (NaN and Inf propagate through it; the entrywise test runs only when
the sum is not finite).

**Policy** (:class:`Guard`; the trainer, :mod:`pdeinv.training.trainer`, only reports):

1. every rejection rolls back to the last good state and multiplies the step size by ``step_factor``
   (½; a test-set blow-up found by the trainer's evaluation also by its overshoot);
2. the run stops after ``max_failures`` rejections *in a row*: a rejection ends the streak only when a
   step numbered at least as high as the last rejected one is accepted (new parameters passed), so
   re-accepting the rolled-back state does not reset the count; and it stops when a rejection finds the
   multiplier already at its floor ``min_scale`` (1e-12: about 40 halvings, the total budget of step-size
   cuts, spent however the rejections were spread); the model is left in the last good state;
3. after ``recover_after`` (50) accepted steps with no rejection the multiplier doubles back toward 1
   (never above), so one noisy batch costs a lowered step for 50 steps, not for the rest of the run.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import torch

from .._checks import count, positive
from ..errors import ConvergenceError, NonFiniteError

ADVICE = "lower the learning rate / eta, or raise tau for HIG"


class Diverged(NonFiniteError):
    """A finite loss beyond the allowed growth over the lowest one so far: rejected like a NaN."""


def trainable(model: torch.nn.Module) -> list[torch.nn.Parameter]:
    """The parameters a rule updates, in ``model.parameters()`` order (its direction's order)."""
    return [p for p in model.parameters() if p.requires_grad]


def finite(t: torch.Tensor) -> bool:
    """Whether every entry of ``t`` is finite: one reduction, ``sum(t)``, which any NaN or Inf makes
    non-finite; only when it is not (those, or finite entries whose sum overflows) the entrywise test
    decides. Same answer as ``isfinite(t).all()``, without its boolean temporary."""
    t = t.detach()
    return math.isfinite(float(t.sum())) or bool(torch.isfinite(t).all())


def describe(t: torch.Tensor) -> str:
    t = t.detach()
    return f"{int(torch.isnan(t).sum())} NaN, {int(torch.isinf(t).sum())} Inf of {t.numel()}"


def resumable(rule) -> bool:
    """Whether ``rule`` saves and restores its state: its declaration (:mod:`pdeinv.methods.protocol`;
    the guard takes declared rules only)."""
    return rule.resumable


def apply_if_finite(rule, state, model: torch.nn.Module, y: torch.Tensor, scale: float = 1.0,
                    max_loss: float = math.inf, snapshot: Snapshot | None = None,
                    target: torch.Tensor | None = None):
    """One step of ``rule`` on batch ``y`` (with ``target`` if given, :mod:`pdeinv.methods.targets`):
    ``(state,
    info)``; refuses a non-finite loss or update, or a loss above ``max_loss``; ``snapshot`` keeps the
    verified pre-step state (module docstring)."""
    try:
        direction, info = rule.update(state, model, y) if target is None else \
            rule.update(state, model, y, target=target)
    except ConvergenceError as err:  # the physics failed where the last update left the network
        raise Diverged(f"the physics did not converge at the network's output ({err}): the previous "
                       f"update blew up; it is undone ({ADVICE})") from err
    params = trainable(model)
    check_update(info, direction, model)
    loss = info["loss"]
    if loss > max_loss:
        raise Diverged(f"the y-loss {loss:.3g} exceeds {max_loss:.3g}, the allowed growth over the lowest "
                       f"loss so far: the previous update blew up; it is undone ({ADVICE})")
    if snapshot is not None:
        snapshot.take(rule, state, model)
    rule.transform.apply(state.transform, params, direction, scale)
    return state._replace(steps=state.steps + 1), info


def step(rule, state, model: torch.nn.Module, y: torch.Tensor):
    """One guarded update at full step size, calibrating the rule first on its first step: ``(state,
    info)`` (one-off use, e.g. ``rule.step``; a run uses a :class:`Guard`)."""
    if state.steps == 0:
        state = rule.calibrate(state, model, y)
    return apply_if_finite(rule, state, model, y)


def check_update(info: dict, direction, model: torch.nn.Module) -> None:
    """Raise :class:`NonFiniteError` unless ``info["loss"]`` and every direction tensor are finite."""
    loss = info.get("loss", math.nan)
    if direction is None or not math.isfinite(loss):
        raise NonFiniteError(f"the y-loss is not finite ({loss}); the update was not applied ({ADVICE})")
    if all(d is None or finite(d) for d in direction):
        return
    names = [n for n, p in model.named_parameters() if p.requires_grad]
    for name, d in zip(names, direction, strict=True):
        if d is not None and not finite(d):
            raise NonFiniteError(f"the update of {name!r} is not finite ({describe(d)}); "
                                 f"it was not applied ({ADVICE})")


def copied(buffer, value):
    """A copy of ``value`` (dicts, lists and tuples of tensors and plain values), each tensor copied into
    the tensor at the same place in ``buffer`` (a previous copy) when shape, dtype and device agree,
    else cloned; plain values deep-copied. Exact; allocates nothing once ``buffer`` fits."""
    if isinstance(value, torch.Tensor):
        fits = isinstance(buffer, torch.Tensor) and buffer.shape == value.shape and \
            buffer.dtype == value.dtype and buffer.device == value.device
        return buffer.copy_(value) if fits else value.detach().clone()
    if isinstance(value, dict):
        old = buffer if isinstance(buffer, dict) else {}
        return {k: copied(old.get(k), v) for k, v in value.items()}
    if type(value) in (list, tuple):  # plain sequences (a namedtuple or a torch.Size is deep-copied whole)
        fits = isinstance(buffer, (list, tuple)) and len(buffer) == len(value)
        old = buffer if fits else [None] * len(value)
        return type(value)(copied(b, v) for b, v in zip(old, value, strict=True))
    return copy.deepcopy(value)


class Snapshot:
    """The last verified parameters and rule state, and the step count they belong to.

    ``step`` is ``None`` until the first :meth:`take`. A rule that does not save its state
    (:func:`resumable`) has its parameters rolled back, not its state.
    """

    def __init__(self):
        self.params: list[torch.Tensor] = []
        self.rule_state: dict | None = None
        self.step: int | None = None

    @torch.no_grad()
    def take(self, rule, state, model: torch.nn.Module, step: int | None = None) -> None:
        """Copy the parameters and the rule's state into the snapshot's buffers (allocated on the first
        take, or when a shape changes; :func:`copied`)."""
        self.params = copied(self.params, [p.detach() for p in trainable(model)])
        if resumable(rule):
            self.rule_state = copied(self.rule_state, rule.state_dict(state))
        self.step = state.steps if step is None else step

    @torch.no_grad()
    def restore(self, rule, state, model: torch.nn.Module):
        """Copy the snapshot back into ``model`` and return the rule state it held."""
        for p, saved in zip(trainable(model), self.params, strict=True):
            p.copy_(saved)
        if self.rule_state is not None:
            state = rule.load_state_dict(state, copy.deepcopy(self.rule_state))
        return state._replace(steps=self.step)

    def saved(self) -> dict | None:
        """For a checkpoint (``None`` before the first :meth:`take`)."""
        if self.step is None:
            return None
        return {"params": self.params, "rule_state": self.rule_state, "step": self.step}

    def load(self, saved: dict | None) -> None:
        if saved is not None:
            self.params = [t.clone() for t in saved["params"]]
            self.rule_state, self.step = saved["rule_state"], int(saved["step"])


@dataclass
class Guard:
    """The guard of one run (policy in the module docstring): ``step`` applies a rule's update if it
    passes, ``reject`` rolls back and lowers the step size or says why the run must stop, ``accept``
    counts a step that passed every check. Its state (multiplier, streak, lowest loss, last good
    state) goes into a checkpoint through :meth:`state_dict`; its settings are configuration."""

    max_failures: int = 5  # rejections in a row that stop the run
    step_factor: float = 0.5  # the multiplier's cut per rejection
    max_loss_growth: float | None = 1e3  # a loss above this × the lowest accepted one is rejected
    min_scale: float = 1e-12  # the multiplier's floor: the budget of cuts (~40 halvings)
    recover_after: int | None = 50  # accepted steps in a row before the multiplier doubles (None: never)
    snapshot_every: int = 10  # accepted steps between copies of the last good state (module docstring)
    scale: float = field(default=1.0, init=False)  # the step-size multiplier
    failures: int = field(default=0, init=False)  # rejections in a row
    failed_at: int = field(default=0, init=False)  # the highest step number rejected
    calm: int = field(default=0, init=False)  # accepted steps since the last rejection or doubling
    best: float = field(default=math.inf, init=False)  # the lowest accepted loss
    good: Snapshot = field(default_factory=Snapshot, init=False)  # the last good state

    def __post_init__(self):
        self.max_failures = count(self.max_failures, "max_failures")
        if not positive(self.step_factor, "step_factor") <= 1:
            raise ValueError(f"step_factor={self.step_factor!r} is not allowed; "
                             "expected 0 < step_factor <= 1")
        if self.max_loss_growth is not None and not positive(self.max_loss_growth, "max_loss_growth") > 1:
            raise ValueError(f"max_loss_growth={self.max_loss_growth!r} is not allowed; "
                             "expected a number > 1 or None")
        if not positive(self.min_scale, "min_scale") <= 1:
            raise ValueError(f"min_scale={self.min_scale!r} is not allowed; expected 0 < min_scale <= 1")
        if self.recover_after is not None:
            self.recover_after = count(self.recover_after, "recover_after")
        self.snapshot_every = count(self.snapshot_every, "snapshot_every")

    def step(self, rule, state, model: torch.nn.Module, y: torch.Tensor, target: torch.Tensor | None = None):
        """:func:`apply_if_finite` at the guard's multiplier and loss limit, keeping the last good state
        every ``snapshot_every`` steps; the loss growth is not checked right after a roll-back (those
        parameters passed once)."""
        verified = self.max_loss_growth is None or self.good.step == state.steps or not self.best > 0
        limit = math.inf if verified else self.best * self.max_loss_growth
        due = self.good.step is None or state.steps >= self.good.step + self.snapshot_every
        state, info = apply_if_finite(rule, state, model, y, self.scale, limit, self.good if due else None,
                                      target=target)
        self.best = min(self.best, float(info["loss"]))
        return state, info

    def accept(self, step: int) -> None:
        """Step ``step`` passed every check (its loss and, if any, the trainer's evaluation)."""
        if step >= self.failed_at:  # new parameters passed: the streak of rejections is over
            self.failures = 0
        self.calm += 1
        if self.recover_after is not None and self.calm >= self.recover_after and self.scale < 1:
            self.scale, self.calm = min(1.0, 2 * self.scale), 0

    def reject(self, rule, state, model: torch.nn.Module, step: int, failed: int,
               overshoot: float | None = None):
        """Rejected step number ``failed``, the run at accepted step ``step``: roll back to the last good
        state and lower the multiplier (by ``overshoot`` too, if given). ``(state, step, note, stop)``:
        the state and step to go on from, what was done, and ``stop`` (why the run must stop) or None."""
        self.failures, self.failed_at, self.calm = self.failures + 1, max(self.failed_at, failed), 0
        note = ""
        if self.good.step is not None and self.good.step < step:  # undo the update that blew up
            state, step = self.good.restore(rule, state, model), self.good.step
            note = f", rolled back to the state after step {step}"
        if self.failures >= self.max_failures:
            return state, step, note, (f"stopped after {self.failures} consecutive rejected steps "
                                       f"(max_failures={self.max_failures})")
        if self.scale <= self.min_scale:
            return state, step, note, (f"stopped: the step size is at its floor, {self.min_scale:g} times "
                                       f"the configured one (min_scale: the budget of cuts, "
                                       f"~{math.log2(1 / self.min_scale):.0f} halvings), and still fails")
        old, self.scale = self.scale, max(self.min_scale, self.scale * self.step_factor * (overshoot or 1.0))
        note += (f", step size scaled by {self.scale / old:.3g} to {self.scale:.3g} of the configured one "
                 f"(failure {self.failures} in a row of at most {self.max_failures}; "
                 f"floor {self.min_scale:g})")
        return state, step, note, None

    def state_dict(self) -> dict:
        return {"scale": self.scale, "failures": self.failures, "failed_at": self.failed_at,
                "calm": self.calm, "best": self.best, "good": self.good.saved()}

    def load_state_dict(self, sd: dict) -> None:
        """``sd`` from :meth:`state_dict` (an older checkpoint's position, without the newer keys, too)."""
        self.scale, self.failures = float(sd.get("scale", 1.0)), int(sd.get("failures", 0))
        self.failed_at, self.calm = int(sd.get("failed_at", 0)), int(sd.get("calm", 0))
        self.best = float(sd.get("best", math.inf))
        self.good.load(sd.get("good"))
