"""Scale-invariant physics (SIP) updates: Holl, Koltun & Thuerey, NeurIPS 2022."""

from __future__ import annotations

import math
import types
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from .._checks import flag, label, positive
from ..inverse.decoder import DecoderTikhonov
from ..inverse.protocol import ReusesForward
from ..nets.protocol import declared
from ..physics.base import LinearOperator
from ..physics.nonlinear import is_linear
from ..problem.definition import Problem
from .base import (
    OptimizerFactory,
    Rule,
    State,
    Update,
    at_lr,
    check_finite,
    gradient,
    prediction,
    sgd,
    y_loss,
)
from .curvature import checked, gauss_newton_max
from .transforms import OptimizerStep

#: entries of one ``(rows, N)`` array in a chunk of :meth:`SIP.update` (2²⁴: 134 MB in float64); larger
#: batches are split by rows. heat_2d at 65 025 unknowns, SIP's full batch of 1 024: chunks of 256 rows
CHUNK_ENTRIES = 2**24

#: ``(y_target, x0) -> x̃`` on numpy ``(B, ·)`` arrays: a local inverse ``P⁻¹_(x0, P x0)``
InverseSimulator = Callable[[np.ndarray, np.ndarray], np.ndarray]


class SIPContext(NamedTuple):
    """What SIP needs from the problem (fixed for the run) and the proxy's curvature (set once by
    :meth:`SIP.calibrate`, saved with the rule state)."""

    operator: LinearOperator
    inverse: InverseSimulator
    curvature: float | None = None
    diagonal: tuple | None = None  # the network's Gauss–Newton diagonal, when it has one (calibrate)
    #: ``(y, x0, y0) -> x̃``: the same inverse given ``y0 = P x0`` (:class:`~pdeinv.inverse.ReusesForward`)
    local: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None
    #: ``x -> P x`` for the network's fields without running the physics, where they lie in a fixed decoder's
    #: span and ``P D`` is known (:meth:`~pdeinv.inverse.decoder.DecoderTikhonov.forward_in_span`); ``None``:
    #: the operator's own forward
    forward: Callable[[np.ndarray], np.ndarray] | None = None
    #: the default decoder inverse when it was built on this network's decoder: the step then runs in the
    #: decoder's coordinates where the network offers them (:meth:`SIP._update_in_span`)
    span: DecoderTikhonov | None = None


def decoder_inverse(problem, model):
    """The default local inverse for a network with a fixed decoder ``x = D c``
    (``model.linear_in_parameters().decoder``: :func:`pdeinv.nets.reduced`): ``x̃ = x + D Δc``, the
    Tikhonov solve of the residual in ``span D`` (:class:`~pdeinv.inverse.decoder.DecoderTikhonov`),
    where observations are exact or a denoised target will be fitted; ``None`` otherwise (the
    problem's own inverse)."""
    from .targets import SpectralWiener

    lin = declared(model).linear_in_parameters()
    noise = problem.noise or 0.0
    if lin is None or lin.decoder is None or (noise and not SpectralWiener().applies(problem, noise, model)):
        return None
    if not is_linear(problem.operator):  # the solve in span D needs a fixed P D: the problem's own inverse
        return None
    return DecoderTikhonov(problem.operator, lin.decoder)


@dataclass(frozen=True)
class SIP(Rule):
    """One SIP step (Holl et al. 2022, Alg. 1)::

        x  = f(y*; θ),   y = P(x),   Δy = η (y* − y),
        x̃  = P⁻¹_(x, y)(y + Δy)                      (local inverse simulator, no gradient)
        L̃  = ½ · mean_i ‖x_i − stopgrad(x̃_i)‖²       (Euclidean, mean over the batch)
        direction = ∇_θ L̃ / λ̂,   θ ← optimizer(direction)

    Only the network is differentiated; the physics runs forward once and the
    inverse once, both in float64 numpy. The inverse keeps the local-inverse contract
    (``P⁻¹_(x, Px)(Px) = x``, :mod:`pdeinv.inverse.protocol`), so ``x̃ − x`` is the regularized
    inverse of the residual ``η (y* − Px)`` and the fixed point is ``Pᵀ(y* − Px) = 0`` in the
    inverse's norm; one that declares :class:`~pdeinv.inverse.ReusesForward` gets the ``y = P(x)``
    computed here (``inverse.local(y + Δy, x, y)``, one forward call fewer per step; it must be
    built on ``problem.operator``, as the defaults are). ``inverse`` defaults to the problem's
    own (``problem.inverse(y_target, x0)``), which for linear ``P`` and η = 1 with
    an exact inverse makes ``x̃`` the exact solution; for a network with a fixed decoder
    (:func:`pdeinv.nets.reduced`) to the solve in the decoder's span (:func:`decoder_inverse`:
    heat_plate 0.0496 → 0.0101 noise-free and 0.142 → 0.127 at 1 % noise, CLI defaults, where SIP's
    Euclidean proxy projected a full-space solution onto the decoder). The y-loss reported in
    ``info["loss"]`` is the GD loss at ``x`` (before the update); ``info["proxy"]``
    is ``L̃``. The guard's step-size multiplier scales the optimizer's lr (η stays:
    it sets the target, not the step). The inverse's output is checked (shape,
    finiteness) before it is trained on: it is a user-supplied strategy.

    ``normalize=True`` divides the proxy gradient by ``λ̂ = λ_max`` of the proxy's Gauss–Newton
    matrix ``G`` (:func:`~.curvature.gauss_newton_max`), measured once on the run's first batch by
    :meth:`calibrate` (the trainer calls it; saved with the state, so a resumed run keeps it).
    A network that knows the diagonal ``d`` of its ``G`` (``model.gauss_newton_diagonal(y)``:
    :class:`pdeinv.nets.Net` with a linear body) is Jacobi-preconditioned first, direction
    ``d⁻¹∇L̃ / λ_max(d⁻¹G)``: for the reduced network, whose fixed decoder scales its columns by
    the prior's amplitudes (for Adam's sake, :func:`pdeinv.nets.prior_basis`), ``G`` is diagonal
    and this is Newton's step; by ``λ_max`` alone its condition number (the prior's amplitude
    ratio, squared) slows the weak directions (heat_plate: x-error 0.148 after 100 steps).
    Plain SGD's learning rate is then in units of the Landweber step ``1/λ_max``: lr 1 is
    stable (below 2) whatever the network's input scale, width or batch size. On the
    whitened linear network the proxy is a linear least-squares problem, SGD on it is a
    Landweber iteration, and its first steps never put energy into directions the physics
    cannot see (Adam's sign-like steps do: :mod:`.presets`). Adam is invariant to
    the division (up to its ε): pass ``normalize=False`` with it. The defaults, normalized SGD at
    lr 1, are what ``pdeinv train --method sip`` runs (with every training row in each step:
    on the whitened linear network the proxy's Hessian is then the identity on the kept
    directions, and one step solves it). ``lr`` sets the optimizer's learning rate (``SIP(lr=0.5)``:
    ``--method sip --lr 0.5``; ``None``: its own).
    """

    inverse: InverseSimulator | None = None
    eta: float = 1.0
    optimizer: OptimizerFactory = field(default_factory=lambda: sgd(1.0))
    normalize: bool = True
    name: str = "sip"
    lr: float | None = None  # the optimizer's learning rate (the CLI's --lr); None: the optimizer's own

    def __post_init__(self):
        label(self.name, "name")
        positive(self.eta, "eta")
        flag(self.normalize, "normalize")
        at_lr(self.optimizer, self.lr)  # checks lr and the optimizer
        if self.inverse is not None and not callable(self.inverse):
            raise TypeError(f"inverse={self.inverse!r} is {type(self.inverse).__name__}; expected None (the "
                            "problem's own) or a local inverse (y_target, x0) -> x̃ (pdeinv.inverse)")

    @property
    def transform(self) -> OptimizerStep:
        return OptimizerStep(at_lr(self.optimizer, self.lr))

    def settings(self) -> dict:
        inverse = "problem" if self.inverse is None else self.inverse.__qualname__ \
            if isinstance(self.inverse, types.FunctionType) else type(self.inverse).__qualname__
        return {"eta": self.eta, "inverse": inverse, "normalize": self.normalize}

    def context(self, problem, model) -> SIPContext:
        inverse = self.inverse if self.inverse is not None else decoder_inverse(problem, model)
        if inverse is None:  # the problem's own; a pdeinv.Problem's calls its inverse_simulator
            inverse = problem.inverse
            simulator = problem.inverse_simulator if isinstance(problem, Problem) else None
        else:
            simulator = inverse
        local = simulator.local if isinstance(simulator, ReusesForward) else None
        # the default decoder inverse was built from this network's decoder: its fields are in span D
        span = inverse if self.inverse is None and isinstance(inverse, DecoderTikhonov) else None
        return SIPContext(problem.operator, inverse, local=local,
                          forward=None if span is None else span.forward_in_span, span=span)

    def calibrate(self, state: State, model: torch.nn.Module, y: torch.Tensor) -> State:
        """``λ̂`` on the batch ``y`` (when ``normalize``): called once, before the first step."""
        if not self.normalize or state.context.curvature is not None:
            return state
        net = declared(model)  # exact curvature where the network declares it (linear in θ)
        diag = net.gauss_newton_diagonal(y)
        if diag is not None:  # a dropped input direction has d = 0 and a zero gradient: leave it alone
            diag = tuple(torch.where(d > 0, d, torch.ones_like(d)) for d in diag)
        lam = net.gauss_newton_max(y) if diag is not None else None
        lam = checked(gauss_newton_max(model, y, diagonal=diag) if lam is None else lam,
                      "SIP(normalize=True): the proxy's curvature")
        return state._replace(context=state.context._replace(curvature=lam, diagonal=diag))

    def state_dict(self, state: State) -> dict:
        return {**super().state_dict(state), "curvature": state.context.curvature}

    def load_state_dict(self, state: State, sd: dict) -> State:
        state = super().load_state_dict(state, sd)
        return state._replace(context=state.context._replace(curvature=sd.get("curvature")))

    def update(self, state: State, model: torch.nn.Module, y_target: torch.Tensor,
               target: torch.Tensor | None = None) -> Update:
        """One SIP direction on the batch, in chunks of rows where its ``(B, N)`` arrays are large
        (:data:`CHUNK_ENTRIES`): the proxy and the loss are means over rows, so the chunks' directions and
        measurements, weighted by their share of the rows, sum to the batch's. The network must treat
        rows independently (every pdeinv network does; a batch-coupled layer such as BatchNorm would see
        the chunks)."""
        op = state.context.operator
        rows = max(1, CHUNK_ENTRIES // max(op.n_in, op.n_out, 1))
        B = y_target.shape[0]
        if B <= rows:
            return self._update(state, model, y_target, target)
        total_dir, total = None, {}
        for i in range(0, B, rows):
            chunk = slice(i, i + rows)
            part = self._update(state, model, y_target[chunk], None if target is None else target[chunk])
            w = min(rows, B - i) / B
            if part.direction is None:  # a non-finite loss: the guard refuses the batch
                return part
            scaled = tuple(None if d is None else w * d for d in part.direction)
            total_dir = scaled if total_dir is None else tuple(
                b if a is None else a if b is None else a + b for a, b in zip(total_dir, scaled, strict=True))
            for k, v in part.info.items():
                total[k] = total.get(k, 0.0) + w * v
        return Update(total_dir, total)

    def _update(self, state: State, model: torch.nn.Module, y_target: torch.Tensor,
                target: torch.Tensor | None = None) -> Update:
        op, inverse, curvature, diagonal, local, forward, span = state.context
        c = None if span is None else declared(model).coefficients(y_target)
        if c is not None:
            return self._update_in_span(state.context, model, prediction(c), y_target if target is None
                                        else target)
        x = prediction(model(y_target))
        x_np = x.detach().cpu().double().numpy()
        yt = (y_target if target is None else target).detach().cpu().double().numpy()
        y = op.forward(x_np) if forward is None else forward(x_np)
        loss = 0.5 * float(((y - yt) ** 2).sum(-1).mean())
        if not math.isfinite(loss):  # the inverse is never called on it; the guard refuses
            return Update(None, {"loss": loss})
        y_step = y + self.eta * (yt - y)
        x_tilde = np.asarray(inverse(y_step, x_np) if local is None else local(y_step, x_np, y))
        if x_tilde.shape != x_np.shape:
            raise ValueError(f"the inverse simulator returned shape {x_tilde.shape}; "
                             f"expected {x_np.shape}")
        target = torch.as_tensor(x_tilde, dtype=x.dtype, device=x.device)
        check_finite("the inverse simulator's x̃", target)
        proxy = y_loss(x, target)  # ½ mean ‖x − x̃‖², target carries no gradient
        direction = self.normalized(gradient(proxy, model), curvature, diagonal)
        return Update(direction, {"loss": loss, "proxy": float(proxy.detach())})

    def _update_in_span(self, context: SIPContext, model: torch.nn.Module, c: torch.Tensor,
                        y_target: torch.Tensor) -> Update:
        """:meth:`_update` for a network ``x = D c`` under the default inverse on its decoder
        (:class:`~pdeinv.inverse.decoder.DecoderTikhonov`), in the decoder's coordinates: ``P x = P̂ c``,
        ``x̃ = D (c + Δc)`` and ``L̃ = ½ mean (c − c̃)ᵀ DᵀD (c − c̃)``, the same loss, direction and
        measurements without forming a ``(B, N)`` field (heat_3d at 29 791 unknowns: seven products of the
        batch with ``(k, N)`` arrays per step before, one with ``P̂`` now)."""
        span = context.span
        c_np = c.detach().cpu().double().numpy()
        yt = y_target.detach().cpu().double().numpy()
        y = span.forward_coefficients(c_np)
        loss = 0.5 * float(((y - yt) ** 2).sum(-1).mean())
        if not math.isfinite(loss):
            return Update(None, {"loss": loss})
        c_tilde = torch.as_tensor(c_np + span.change_coefficients(self.eta * (yt - y)), dtype=c.dtype,
                                  device=c.device)
        check_finite("the inverse simulator's x̃", c_tilde)
        e = c - c_tilde
        proxy = 0.5 * ((e @ torch.as_tensor(span.gram, dtype=c.dtype, device=c.device)) * e).sum(-1).mean()
        direction = self.normalized(gradient(proxy, model), context.curvature, context.diagonal)
        return Update(direction, {"loss": loss, "proxy": float(proxy.detach())})

    def normalized(self, direction: tuple, curvature: float | None, diagonal: tuple | None) -> tuple:
        """``d⁻¹ ∇ / λ̂`` (the class docstring) when ``normalize``, else ``direction`` unchanged."""
        if not self.normalize:
            return direction
        if curvature is None:
            raise ValueError(f"{type(self).__name__}(normalize=True) needs its curvature: call state = "
                             "rule.calibrate(state, model, y) on a first batch (pdeinv.Trainer and "
                             "rule.step do)")
        scale = (None,) * len(direction) if diagonal is None else diagonal
        return tuple(None if d is None else (d if s is None else d / s) / curvature
                     for d, s in zip(direction, scale, strict=True))
