"""Stopping rules that never look at ``x``: when to stop training on noisy observations.

Every update rule *semi-converges* on noisy data: the physics loss is minimized by
the unregularized inverse, which fits the noise, so the x-error falls, then rises
while the y-residual keeps falling. The iteration count is the regularization
parameter, and Morozov's discrepancy principle chooses it as it chooses Tikhonov's
α (Engl, Hanke, Neubauer, *Regularization of Inverse Problems*, §4.3 and §6):
stop at the first iterate whose residual reaches the noise,

    ρ_k = √( Σ_i ‖P f_k(y_i) − y_i‖² / Σ_i m σ_i² ) ≤ τ,      τ > 1,

on **held-out observations** ``y_i`` (the network cannot have memorized their
noise, so ``ρ`` does not drop below the level a good reconstruction leaves).
``σ_i² = δ²/(1+δ²) · mean(y_i²)`` is the per-component variance of the relative
noise ``δ`` (:func:`pdeinv.inverse.noise.noise_variance`), so ``ρ = 1`` is the residual of
the true ``x``. ``δ`` is the problem's level when it knows one, otherwise (or with
``noise="estimate"``) estimated from the training observations
(:func:`pdeinv.inverse.noise.estimate_noise`).

A rule is a strategy object with explicit state, like the update rules::

    state = rule.init(problem, y_train, y_val)        # y: numpy (n, m) observations
    state, info, stop = rule.check(state, model)      # every rule.every accepted steps
    rule.describe(state) -> dict                      # what the rule used, for metrics.json

``rule.n_val`` held-out observations are drawn by the trainer (observations only;
their ``x`` is discarded). ``info`` is merged into the history row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np
import torch

from .._checks import count, positive
from ..inverse.decoder import known_svd
from ..inverse.noise import estimate_noise
from ..nets.protocol import declared

#: a step that moved no trainable parameter by more than this, relative to the largest, changed nothing
#: (:func:`converged`): SIP at its fixed point moves them by rounding (wave_2d at 1 %: 4e-16 at 121 unknowns,
#: 3e-14 at 961), and a step that still improves x by far more (noise-free heat, steps 25–30: ≥ 2.6e-5)
STILL = 1e-10

#: ... and whose loss sits within ``(ROUNDING_ULPS·eps)² · m`` of the first (~100 ulps per observation)
ROUNDING_ULPS = 100.0

#: accepted steps in a row that are :func:`converged` before a run stops
STILL_STEPS = 2


def parameters(model: torch.nn.Module) -> torch.Tensor:
    """The trainable parameters as one flat copy (:func:`converged` compares two)."""
    return torch.cat([p.detach().reshape(-1).clone() for p in model.parameters() if p.requires_grad])


def converged(before: torch.Tensor, after: torch.Tensor, loss: float, first: float, m: int) -> bool:
    """Whether a step found the rule at its fixed point: it left every trainable parameter where it was (to
    :data:`STILL` of the largest) at a loss at float64 rounding of the first (``loss ≤ (ROUNDING_ULPS·eps)²
    · m · first``, ``m`` observations). Why: full-batch steps after the fixed point change nothing (SIP on
    wave_3d reaches it in three of its 30). Neither test alone: noise-free heat reaches a rounding-level loss
    while its weak modes still improve ``x``, and a diverged network's huge weights make any step look
    still."""
    if before.numel() == 0 or before.shape != after.shape or not at_rounding(loss, first, m):
        return False
    scale = float(after.abs().max())
    return math.isfinite(scale) and scale > 0 and float((after - before).abs().max()) <= STILL * scale


def at_rounding(loss: float, first: float, m: int) -> bool:
    """``loss ≤ (ROUNDING_ULPS·eps)² · m · first`` (finite, ``first > 0``): :func:`converged`'s loss test."""
    eps = np.finfo(float).eps
    return math.isfinite(loss) and first > 0 and loss <= (ROUNDING_ULPS * eps) ** 2 * m * first


def finished(at, steps: int | None, time_budget: float | None) -> bool:
    """Whether a run at ``at`` (its accepted ``step``, ``wall`` seconds of training, ``stopped_by``) is
    over: a stopping rule or callback ended it, or it reached ``steps`` or ``time_budget`` (each may be
    None: no limit); never before its first step."""
    return at.step >= 1 and (at.stopped_by is not None or (steps is not None and at.step >= steps) or (
        time_budget is not None and at.wall >= time_budget))


@torch.no_grad()
def observe(operator, model: torch.nn.Module, y: torch.Tensor) -> tuple[np.ndarray, np.ndarray | None]:
    """``(f(y), P f(y))`` as float64 numpy; ``P f(y)`` is ``None`` when ``f(y)`` is not finite (the physics is
    then not called). Where ``f(y) = c Dᵀ`` ends in a decoder whose ``P D`` this run already computed
    (:func:`~pdeinv.inverse.decoder.known_svd`), ``P f(y) = P̂ c`` without the physics: 128 held-out rows of
    wave_3d at 29 791 unknowns cost ~30 s of Newmark steps per check otherwise."""
    xhat = model(y).double().cpu().numpy()
    if not np.isfinite(xhat).all():
        return xhat, None
    net = declared(model)
    svd = None if net.decoder is None else known_svd(operator, net.decoder)
    c = None if svd is None else net.coefficients(y)
    return xhat, operator.forward(xhat) if c is None else svd.forward(c.double().cpu().numpy())


def held_out_residual(operator, y_val: np.ndarray, model: torch.nn.Module) -> float:
    """``Σ_i ‖P f(y_i) − y_i‖²`` over held-out observations ``y_val`` (:func:`observe`); ``inf`` when ``f``
    is not finite there (the physics is then not called)."""
    param = next(iter(model.parameters()), None)
    dtype = param.dtype if param is not None else torch.float32
    device = param.device if param is not None else None
    _, yhat = observe(operator, model, torch.as_tensor(y_val, dtype=dtype, device=device))
    return np.inf if yhat is None else float(np.sum((yhat - y_val) ** 2))


class DiscrepancyState(NamedTuple):
    operator: object
    y_val: np.ndarray
    noise_sq: float  # Σ_i m σ_i²
    noise: float  # the relative level δ used
    noise_source: str  # "problem" or "estimate"


@runtime_checkable
class StopRule(Protocol):
    """What the trainer asks of a stopping rule: its held-out rows ``n_val``, how often it checks
    (``every``), ``init(problem, y, rows) -> state`` and ``check(state, ...)``."""

    n_val: int
    every: int

    def init(self, problem, y, rows): ...

    def check(self, *args, **kwargs): ...


@dataclass(frozen=True)
class DiscrepancyStop:
    """Stop once the held-out residual ratio ``ρ ≤ tau`` (module docstring).

    ``noise``: ``None`` takes the problem's level (a noise-free problem makes the
    rule inert: it never fires); ``"estimate"`` estimates it from the training
    observations; a number is the relative level itself.
    ``tau = 1.1`` as for Morozov's α (:class:`pdeinv.inverse.Discrepancy`).
    """

    tau: float = 1.1
    noise: float | str | None = None
    every: int = 10
    n_val: int = 128
    name: str = "discrepancy"

    def __post_init__(self):
        positive(self.tau, "tau")
        count(self.every, "every")
        count(self.n_val, "n_val")
        if not (self.noise is None or self.noise == "estimate"
                or (isinstance(self.noise, (int, float)) and self.noise >= 0)):
            raise ValueError(f"noise={self.noise!r} is not allowed; expected None, 'estimate' or a "
                             "relative level >= 0")

    def init(self, problem, y_train: np.ndarray, y_val: np.ndarray) -> DiscrepancyState:
        if self.noise == "estimate":
            delta, source = estimate_noise(y_train), "estimate"
        elif self.noise is None:
            delta, source = float(problem.noise or 0.0), "problem"
        else:
            delta, source = float(self.noise), "given"
        y_val = np.asarray(y_val, dtype=float)
        sigma2 = delta**2 / (1.0 + delta**2) * np.mean(y_val**2, axis=1)
        return DiscrepancyState(problem.operator, y_val, float(np.sum(sigma2) * y_val.shape[1]), delta,
                                source)

    def describe(self, state: DiscrepancyState) -> dict:
        return {"tau": self.tau, "noise": state.noise, "noise_source": state.noise_source}

    @torch.no_grad()
    def check(self, state: DiscrepancyState, model: torch.nn.Module):
        if state.noise_sq == 0:  # noise-free: nothing to stop for, and nothing to compute
            return state, {"discrepancy": np.inf}, False
        r2 = held_out_residual(state.operator, state.y_val, model)
        if not np.isfinite(r2):
            return state, {"discrepancy": np.inf}, False
        ratio = float(np.sqrt(r2 / state.noise_sq))
        return state, {"discrepancy": ratio}, bool(ratio <= self.tau)


class PlateauState(NamedTuple):
    operator: object
    y_val: np.ndarray
    best: float  # the lowest held-out residual ‖P f(y) − y‖² so far
    bad: int  # checks in a row without a relative gain of min_gain over it
    kept: dict | None = None  # the network's state dict at ``best`` (restored when the rule fires)


@dataclass(frozen=True)
class PlateauStop:
    """Stop once the held-out residual ``r = Σ_i ‖P f(y_i) − y_i‖²`` has not fallen below
    ``(1 − min_gain)`` of its lowest value for ``patience`` checks in a row (every ``every`` accepted
    steps, on ``n_val`` held-out observations; never looks at ``x``).

    For rules whose steps are expensive and converge in a few (SIP on nonlinear physics: every step
    linearizes the physics and solves for every training row; on allen_cahn_2d the loss stops falling
    after three of SIP's 30). On noisy data the held-out residual
    stops falling once the network fits the training rows' noise (it cannot fit the held-out noise): an
    early stop on held-out data, as the discrepancy principle is. When it fires, the network is put back
    to its parameters at the lowest residual (one copy of its state dict is kept): a run's held-out
    residual can rise from its first step on while its training loss falls (SIP on sine_gordon_2d at 16 129
    unknowns). The state restarts on a resumed run."""

    min_gain: float = 0.01
    patience: int = 3
    every: int = 1
    n_val: int = 128
    name: str = "plateau"

    def __post_init__(self):
        positive(self.min_gain, "min_gain")
        count(self.patience, "patience")
        count(self.every, "every")
        count(self.n_val, "n_val")

    def init(self, problem, y_train: np.ndarray, y_val: np.ndarray) -> PlateauState:
        return PlateauState(problem.operator, np.asarray(y_val, dtype=float), np.inf, 0)

    def describe(self, state: PlateauState) -> dict:
        return {"min_gain": self.min_gain, "patience": self.patience, "every": self.every}

    @torch.no_grad()
    def check(self, state: PlateauState, model: torch.nn.Module):
        r2 = held_out_residual(state.operator, state.y_val, model)
        gained = r2 < (1 - self.min_gain) * state.best
        kept = state.kept
        if r2 < state.best or kept is None:
            kept = {k: v.detach().clone() for k, v in model.state_dict().items()}
        state = state._replace(best=min(r2, state.best), bad=0 if gained else state.bad + 1, kept=kept)
        fired = state.bad >= self.patience
        if fired:
            model.load_state_dict(state.kept)
        return state, {"plateau": r2}, fired


def chosen(problem, steps: int | None = None, model=None):
    """The stopping rule a run gets by default (``Trainer(stop="auto")``, ``pdeinv train --stop auto``):

    * nonlinear physics (declared): :class:`PlateauStop` checked about 30 times a run (every
      ``steps // 30`` steps; SIP's 30: every step). The discrepancy stop never fired in the nonlinear runs
      of benchmarks/notes/nonlinear.md, and SIP's steps there cost 75 s each after the third had converged;
    * noise-free linear physics: none (the rule's steps);
    * noisy linear physics: none where the trainer fits its denoised target
      (:class:`pdeinv.methods.targets.SpectralWiener`): its fixed point is regularized, and a discrepancy
      stop would only end slower rules (HIG: 0.141 at step 10 against 0.12 at step 100 on heat_2d at 1 %)
      before they reach it; else :class:`DiscrepancyStop` (the problem's level, or one estimated).

    Whether the target applies is asked with ``model``: a network with a prior decoder gets the Wiener
    filter in the basis of ``P D`` where the operator has no spectral basis of its own. ``model=None``
    stands for the default network, which has a prior decoder where the operator is not reversible
    (:mod:`pdeinv.nets.defaults`)."""
    from ..methods.targets import SpectralWiener
    from ..physics.capabilities import reversible
    from ..physics.nonlinear import is_linear

    if not is_linear(problem.operator):
        return PlateauStop(every=max(1, (steps or 30) // 30))
    if not problem.noise:
        return None
    wiener = SpectralWiener()
    decoded = model is None and not reversible(problem.operator)
    if decoded or wiener.applies(problem, problem.noise, model):
        return None
    return DiscrepancyStop(noise=None if problem.noise else "estimate")
