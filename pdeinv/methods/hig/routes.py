"""HIG's routes as strategy objects: how the Jacobian is formed, and how it is decomposed.

A *route* turns one batch into the HIG direction ``−η V Λ^e Uᵀ g`` (see :class:`~.hig.HIG`):

* :class:`Dense` forms the stacked Jacobian ``J`` (rows ``B·n_out``, columns the
  trainable parameters) with a Jacobian strategy — :class:`Reverse` (one adjoint
  physics call on ``B·n_out`` unit cotangents) or :class:`Forward` (one forward
  physics call on ``B·n_params`` network Jacobian columns) — and decomposes it
  with :class:`SVD`, :class:`Gram` or :class:`GramOrSVD`; on a dense network :class:`Structured`
  builds the same ``J`` (or only ``J Jᵀ``) from its layers instead (:mod:`.hig_structured`);
* :class:`MatrixFree` never forms ``J`` (:mod:`.hig_randomized`);
* :class:`LastLayer` never forms ``J`` either: a dense network's last layer takes the exact step on its
  hidden features, the hidden layers none (:mod:`.hig_layers` says what is approximated).

:class:`~.kronecker.Kronecker` takes the exact step without ``J`` for a network linear in its
parameters (:mod:`.kron`, :mod:`.fixed`). :data:`ROUTES` — the one table every step goes through —
maps a route name to the candidates tried in order; the first
whose memory fits ``max_jacobian_gb`` is taken (so ``"auto"`` leaves the dense Jacobian
only when it does not fit: then a dense network takes :class:`LastLayer`, any other the
matrix-free route). :data:`JACOBIANS` maps a Jacobian
name to its strategy; ``"auto"`` takes the one with fewer physics columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from torch import nn
from torch.func import functional_call, jacrev, vmap

from ...inverse.decoder import decoded_svd
from ...physics.bridge import apply
from ...physics.nonlinear import is_linear, require_linear
from ..base import check_finite
from . import layers as hig_layers
from . import structured as hig_structured
from .randomized import activation_bytes, memory_bytes, randomized_direction


class Batch(NamedTuple):
    """One batch as the routes see it: the model as a function of its trainable parameters."""

    model: torch.nn.Module
    op: object
    y: torch.Tensor
    params: dict
    frozen: dict
    rows: int
    n_params: int

    @classmethod
    def of(cls, model, op, y) -> Batch:
        params = {n: p.detach() for n, p in model.named_parameters() if p.requires_grad}
        frozen = {n: p.detach() for n, p in model.named_parameters() if not p.requires_grad}
        frozen.update(dict(model.named_buffers()))
        n_params = sum(p.numel() for p in params.values())
        return cls(model, op, y, params, frozen, y.shape[0] * op.n_out, n_params)

    def double(self) -> Batch:
        """The same batch in float64: parameters, floating buffers and observations."""
        cast = {n: t.double() if t.is_floating_point() else t for n, t in self.frozen.items()}
        return self._replace(y=self.y.detach().double(), frozen=cast,
                             params={n: p.double() for n, p in self.params.items()})

    def f(self, p, y):
        return functional_call(self.model, (p, self.frozen), (y,))

    def stack(self, jac: dict, size: int) -> torch.Tensor:
        """``(B, size, n_params)`` from a dict of per-parameter Jacobians (parameter order)."""
        return torch.cat([jac[n].reshape(self.y.shape[0], size, -1) for n in self.params], -1)


class JacobianRoute:
    """What the routes that form ``J`` or its factors share: the step from their :meth:`direction`."""

    def step(self, rule, b: Batch, op, Q, goal: torch.Tensor, steps: int):
        """The residual ``g`` of the batch (its part in ``range(P)``, ``Q``), the route's direction,
        scaled by ``rule.unit``; ``(None, loss)`` for a non-finite loss."""
        from ..base import Update, prediction, y_loss

        with torch.no_grad():
            y = apply(op, prediction(b.model(b.y)))
        r = (y - goal).double()  # g: per-sample residuals, not divided by B (HIG's docstring)
        loss = float(y_loss(r, torch.zeros_like(r)))
        if not math.isfinite(loss):
            return Update(None, {"loss": loss})
        r = r if Q is None else r @ Q  # the residual's part in range(P); the rest no step can change
        delta, info = self.direction(b, r.reshape(b.rows), rule, steps)
        delta = delta * rule.unit(info)
        sizes = [p.numel() for p in b.params.values()]
        parts = [d.view(p.shape) for d, p in zip(torch.split(delta, sizes), b.params.values(), strict=True)]
        return Update(tuple(parts), {**info, "loss": loss})


# -- how J is formed ---------------------------------------------------------------------------------

class Reverse:
    """``vmap(jacrev(P ∘ f))``: one adjoint physics call on ``B · n_out`` unit cotangents."""

    name = "reverse"

    def choose(self, b: Batch):
        return self

    def extra_bytes(self, b: Batch) -> int:
        return 0

    def jacobian(self, b: Batch) -> torch.Tensor:
        jac = vmap(jacrev(lambda p, yi: apply(b.op, b.f(p, yi))), in_dims=(None, 0))(b.params, b.y)
        return b.stack(jac, b.op.n_out)


class Forward:
    """``vmap(jacrev(f))`` for ``∂x/∂θ``, then one forward physics call on its ``B · n_params`` columns."""

    name = "forward"

    def choose(self, b: Batch):
        return self

    def extra_bytes(self, b: Batch) -> int:  # ∂x/∂θ (float32) and the physics' float64 copy
        B = b.y.shape[0]
        return B * b.op.n_in * b.n_params * 4 + B * b.n_params * b.op.n_out * 8

    def jacobian(self, b: Batch) -> torch.Tensor:
        B, op = b.y.shape[0], b.op
        Jx = b.stack(vmap(jacrev(b.f), in_dims=(None, 0))(b.params, b.y), op.n_in)  # (B, n_in, P)
        cols = apply(op, Jx.transpose(1, 2).reshape(B * b.n_params, op.n_in))
        return cols.reshape(B, b.n_params, op.n_out).transpose(1, 2)


class Chain:
    """``P'(x_i) · ∂x_i/∂θ``: the physics' own per-row Jacobians (its ``jacobian(X)``, e.g.
    :meth:`pdeinv.physics.reaction.ReactionHeat.jacobian`: one reverse sweep of exact tangent solves on all
    unit cotangents, no nonlinear run per cotangent) times ``∂x_i/∂θ`` by ``vmap(jacrev(f))``."""

    name = "chain"

    def choose(self, b: Batch):
        if b.op.jacobian is None:
            raise ValueError(f"HIG(jacobian='chain') needs a physics with per-row Jacobians (jacobian(X)); "
                             f"{type(b.op).__name__} has none: use jacobian='auto', 'forward' or 'reverse'")
        return self

    def extra_bytes(self, b: Batch) -> int:  # ∂x/∂θ (float32, then float64) and the physics' Jacobians
        B = b.y.shape[0]
        return B * b.op.n_in * b.n_params * 12 + b.op.jacobian_bytes(B)

    def jacobian(self, b: Batch) -> torch.Tensor:
        Jx = b.stack(vmap(jacrev(b.f), in_dims=(None, 0))(b.params, b.y), b.op.n_in)  # (B, n_in, P)
        with torch.no_grad():
            x = b.f(b.params, b.y).double().numpy()
        return torch.from_numpy(b.op.jacobian(x)) @ Jx.double()


class FewerColumns:
    """``"auto"``: the physics' own Jacobians where it has them (:class:`Chain`), else reverse unless the
    network has fewer parameters than observations."""

    def choose(self, b: Batch):
        if b.op.jacobian is not None:
            return JACOBIANS["chain"]
        return JACOBIANS["reverse" if b.op.n_out <= b.n_params else "forward"]


#: Jacobian name -> strategy; ``strategy.choose(batch)`` is the concrete one for that batch
JACOBIANS = {"auto": FewerColumns(), "forward": Forward(), "reverse": Reverse(), "chain": Chain()}


# -- how J is decomposed ----------------------------------------------------------------------------

def _kept(s: np.ndarray, tau: float) -> np.ndarray:
    """Singular values kept: ``σ > τ · σ_max`` (and nonzero); the others are dropped, never clamped."""
    return (s > tau * s.max()) & (s > 0)


class SVD:
    """float64 thin SVD ``J = U Λ Vᵀ``; ``Δθ = −η V Λ^e Uᵀ g``."""

    name = "svd"
    bytes_per_entry = 4 + 8 + 8  # float32 from torch.func + float64 copy + LAPACK workspace
    cond_max = float("inf")  # never refuses a conditioning

    def direction(self, J, g, rule):
        U, s, Vt = np.linalg.svd(J.numpy(), full_matrices=False)
        keep = _kept(s, rule.tau)
        Uk, sk, Vk = U[:, keep], s[keep], Vt[keep]
        delta = -rule.eta * (Vk.T @ (sk ** rule.exponent * (Uk.T @ g.numpy())))
        return torch.from_numpy(delta), dict(route="svd", rank=int(keep.sum()), cond=float(s[0] / sk.min()),
                                             sigma_max=float(s[0]))


@dataclass(frozen=True)
class Gram:
    """float64 ``eigh(J Jᵀ) = U Λ² Uᵀ``, ``Δθ = −η Jᵀ U Λ^(e−1) Uᵀ g`` (``V = Jᵀ U Λ⁻¹``).

    Squaring doubles the condition number's exponent (relative error of the smallest
    kept direction ≈ 2e-16 · cond²). With ``cond_max`` finite the result is refused
    (``None``) when the kept part's condition number exceeds it.
    """

    cond_max: float = float("inf")
    name = "gram"
    bytes_per_entry = 4 + 8

    def direction(self, J, g, rule):
        lam2, U = np.linalg.eigh((J @ J.T).numpy())
        s = np.sqrt(lam2.clip(min=0))
        keep = _kept(s, rule.tau)
        cond = float(s.max() / s[keep].min())
        if cond > self.cond_max:
            return None, {"gram_rejected": cond}
        Uk, sk = U[:, keep], s[keep]
        coef = torch.from_numpy(Uk @ (sk ** (rule.exponent - 1) * (Uk.T @ g.numpy())))
        return -rule.eta * (J.T @ coef), dict(route="gram", rank=int(keep.sum()), cond=cond,
                                              sigma_max=float(s.max()))


@dataclass(frozen=True)
class GramOrSVD:
    """Gram when the kept condition number is at most ``cond_max``, else SVD (``info["gram_rejected"]``)."""

    cond_max: float
    name = "gram"
    bytes_per_entry = SVD.bytes_per_entry  # it may fall back to the SVD: budget for it (not Gram's 12)

    def direction(self, J, g, rule):
        delta, info = Gram(self.cond_max).direction(J, g, rule)
        if delta is not None:
            return delta, info
        delta, more = SVD().direction(J, g, rule)
        return delta, {**info, **more}


def auto_decomposition(rows: int, n_params: int, cond_max: float):
    """Gram (guarded by ``cond_max``) when rows ≤ parameters, else SVD: ~10–20× faster when rows ≪ params."""
    return GramOrSVD(cond_max) if rows <= n_params else SVD()


# -- routes: the whole direction -------------------------------------------------------------------

@dataclass(frozen=True)
class Dense(JacobianRoute):
    """Form ``J`` with ``jacobian``, check it, decompose it with ``decomposition``."""

    jacobian: object
    decomposition: object

    @property
    def name(self) -> str:
        return self.decomposition.name

    def memory(self, b: Batch) -> int:
        return b.rows * b.n_params * self.decomposition.bytes_per_entry + self.jacobian.extra_bytes(b)

    def describe(self, b: Batch) -> str:
        return f"dense route: {self.memory(b) / 2**30:.3g} GB"

    def direction(self, b: Batch, r: torch.Tensor, rule, step: int):
        J = self.jacobian.jacobian(b).reshape(b.rows, b.n_params).double()
        check_finite("the HIG Jacobian", J)  # LAPACK on NaN fails or hangs
        delta, info = self.decomposition.direction(J, r, rule)
        return delta, {**info, "jacobian": self.jacobian.name}


@dataclass(frozen=True)
class MatrixFree(JacobianRoute):
    """Rank-``probes`` randomized SVD from jvp/vjp products, probes from ``SeedSequence([seed, step])``."""

    probes: int
    power_iters: int
    seed: int
    name = "randomized"

    def memory(self, b: Batch) -> int:
        """The sketch's arrays and one chunk of probes' activations (a float64 forward of the batch)."""
        return memory_bytes(b.n_params, min(self.probes, b.rows, b.n_params), b.rows, activation_bytes(b))

    def describe(self, b: Batch) -> str:
        return f"matrix-free route: {self.memory(b) / 2**30:.3g} GB with probes={self.probes}"

    def direction(self, b: Batch, r: torch.Tensor, rule, step: int):
        seed = int(np.random.SeedSequence([self.seed, step]).generate_state(1)[0])
        delta, info = randomized_direction(b, r, self.probes, self.power_iters, rule.tau, rule.exponent,
                                           rule.eta, seed, activation_bytes(b))
        return delta, {**info, "jacobian": "matrix-free"}


@dataclass(frozen=True)
class LastLayer(JacobianRoute):
    """The exact HIG step of a dense network's last layer on its hidden features; the hidden layers take
    no step (:mod:`.hig_layers` says why). ``lin``, ``names``: :func:`.hig_layers.last_layer`."""

    lin: object
    names: tuple
    name = "last_layer"

    def memory(self, b: Batch) -> int:  # the features, residuals and a B × B or k̃ × k̃ Gram, float64
        B, k = b.y.shape[0], self.lin.layer.in_features + 1
        return 8 * (B * k + B * b.op.n_out + min(B, k) ** 2 + k * self.lin.layer.out_features)

    def describe(self, b: Batch) -> str:
        return f"last-layer route: {self.memory(b) / 2**30:.3g} GB"

    def direction(self, b: Batch, r: torch.Tensor, rule, step: int):
        fac = decoded_svd(b.op, self.lin.decoder)
        R = r.reshape(b.y.shape[0], -1).numpy()
        steps, info = hig_layers.direction(self.lin, self.names, fac, b.y, R, rule.eta, rule.tau,
                                           rule.exponent)
        parts = [steps[n].reshape(-1) if n in steps else torch.zeros(p.numel(), dtype=torch.float64)
                 for n, p in b.params.items()]
        return torch.cat(parts), {**info, "jacobian": "none"}


def _last_layer(b: Batch) -> LastLayer:
    require_linear(b.op, "HIG(route='last_layer') (it steps on P's SVD on the decoder)")
    return LastLayer(*hig_layers.last_layer(b.model))


def _last_layer_if_dense(b: Batch) -> list:
    """``[LastLayer]`` for a dense network whose last layer is trainable on linear physics, else ``[]``."""
    if not is_linear(b.op):
        return []
    try:
        return [_last_layer(b)]
    except ValueError:
        return []


@dataclass(frozen=True)
class Structured(JacobianRoute):
    """The dense routes' exact step with ``J`` (or only ``J Jᵀ``) built from a dense network's layer
    structure (:mod:`.hig_structured`) instead of ``torch.func``; ``decomposition``: :class:`SVD`,
    :class:`Gram` or :class:`GramOrSVD`, whose ``info`` it gives."""

    decoder: object
    decomposition: object

    @property
    def name(self) -> str:
        return self.decomposition.name

    def memory(self, b: Batch) -> int:  # as the dense route: its SVD forms J
        return b.rows * b.n_params * self.decomposition.bytes_per_entry

    def describe(self, b: Batch) -> str:
        return f"structured route: {self.memory(b) / 2**30:.3g} GB"

    def direction(self, b: Batch, r: torch.Tensor, rule, step: int):
        fac = decoded_svd(b.op, self.decoder)
        ids = {id(p) for n, p in b.model.named_parameters() if n in b.params}
        rows = hig_structured.Rows(b.model, fac, b.y, r.reshape(b.y.shape[0], -1).numpy(), ids)
        for _, E, H in rows.layers:  # LAPACK on NaN fails or hangs
            check_finite("the HIG Jacobian factors", E)
            check_finite("the HIG Jacobian factors", H)
        info = {}
        if not isinstance(self.decomposition, SVD):  # Gram's cond_max is infinite: never refused
            delta, info = self._gram(b, rows, rule)
            if delta is not None:
                return delta, {**info, "jacobian": "structured"}
        J = rows.jacobian()
        J = torch.cat([_columns(b, J, n) for n in b.params], 1)
        delta, more = SVD().direction(J, rows.g, rule)
        return delta, {**info, **more, "jacobian": "structured"}

    def _gram(self, b: Batch, rows, rule):
        """:class:`Gram`'s step from the factors' ``J Jᵀ``, ``Jᵀ c``; ``(None, info)`` past ``cond_max``."""
        lam2, U = np.linalg.eigh(rows.gram().numpy())
        s = np.sqrt(lam2.clip(min=0))
        keep = _kept(s, rule.tau)
        cond = float(s.max() / s[keep].min())
        if cond > self.decomposition.cond_max:
            return None, {"gram_rejected": cond}
        Uk, sk = U[:, keep], s[keep]
        c = torch.from_numpy(Uk @ (sk ** (rule.exponent - 1) * (Uk.T @ rows.g.numpy())))
        parts = rows.transpose_times(-rule.eta * c)
        blocks = {m: t[None] for m, t in parts.items()}
        delta = torch.cat([_columns(b, blocks, n).reshape(-1) for n in b.params])
        return delta, dict(route="gram", rank=int(keep.sum()), cond=cond, sigma_max=float(s.max()))


def _columns(b: Batch, per_layer: dict, name: str) -> torch.Tensor:
    """Parameter ``name``'s columns of ``rows × n_out × (n_in[+1])`` per-layer blocks, flattened."""
    for m, t in per_layer.items():
        if m.weight is b.model.get_parameter(name):
            return t[:, :, : m.in_features].reshape(len(t), -1)
        if m.bias is not None and m.bias is b.model.get_parameter(name):
            return t[:, :, -1]
    raise KeyError(name)


def _structured(rule, b: Batch):
    """:class:`Structured` when ``b.model`` is a dense network whose trainable parameters are whole
    ``nn.Linear`` layers (:func:`.hig_layers.body`) and the physics is linear (the route builds ``J`` from
    ``P``'s SVD on the decoder), else ``None``."""
    if not is_linear(b.op):
        return None
    try:
        _, mods, decoder = hig_layers.body(b.model, "auto")
    except ValueError:
        return None
    linears = [m for m in mods if isinstance(m, nn.Linear)]
    inside = {id(p) for m in linears for p in m.parameters()}
    if any(id(p) not in inside for n, p in b.model.named_parameters() if n in b.params) or \
            any(len({p.requires_grad for p in m.parameters()}) > 1 for m in linears):
        return None
    return Structured(decoder, DECOMPOSITIONS[rule.route](rule, b.rows, b.n_params))


#: decomposition name -> (rule, rows, n_params) -> decomposition of a dense J
DECOMPOSITIONS = {
    "auto": lambda rule, rows, n_params: auto_decomposition(rows, n_params, rule.gram_cond_max),
    "svd": lambda *_: SVD(),
    "gram": lambda *_: Gram(),
}


def _dense(rule, b: Batch):
    """The dense route: :class:`Structured` for a dense network, else :class:`Dense` (``torch.func``)."""
    return _structured(rule, b) or _jacobian(rule, b)


def _jacobian(rule, b: Batch) -> Dense:
    return Dense(JACOBIANS[rule.jacobian].choose(b), DECOMPOSITIONS[rule.route](rule, b.rows, b.n_params))


def _matrix_free(rule) -> MatrixFree:
    return MatrixFree(rule.probes, rule.power_iters, rule.seed)


#: route name -> (rule, batch) -> candidate routes, in order of preference
ROUTES = {
    # a network linear in its parameters takes the exact Kronecker step (kron: its route, built once per
    # run by the rule); a dense network whose J does not fit: the last layer's exact step beat the
    # matrix-free route at equal steps and wall time (heat_2d, wave_2d, MLP (64, 64); .layers)
    "auto": lambda rule, b, kron: [kron] if kron is not None else [
        _dense(rule, b), *_last_layer_if_dense(b), _matrix_free(rule)],
    "kronecker": lambda rule, b, kron: [kron],
    "svd": lambda rule, b, kron: [_dense(rule, b)],
    "gram": lambda rule, b, kron: [_dense(rule, b)],
    "randomized": lambda rule, b, kron: [_matrix_free(rule)],
    "last_layer": lambda rule, b, kron: [_last_layer(b)],
}
