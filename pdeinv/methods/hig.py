"""Half-inverse gradients (HIG): Schnell, Holl & Thuerey, ICLR 2022."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from torch.func import functional_call, jacrev, vmap

from .._checks import choice, count, nonnegative, positive
from ..autograd import apply
from ..physics.base import LinearOperator
from .base import check_finite
from .hig_randomized import memory_bytes, randomized_direction

#: bytes per Jacobian entry held at once: float32 from torch.func + the float64 copy
_BYTES = {"gram": 4 + 8, "svd": 4 + 8 + 8}


class HIGState(NamedTuple):
    operator: LinearOperator
    steps: int = 0
    scale: float = 1.0  # the step is ``scale · η``; lowered by :meth:`HIG.scale_step`


@dataclass(frozen=True)
class HIG:
    """``Δθ = −η · V Λ^e Uᵀ g`` from the stacked Jacobian ``J = U Λ Vᵀ`` (e = ``exponent``).

    ``J`` stacks the per-sample Jacobians ``∂y_i/∂θ = P · ∂x_i/∂θ`` of network and
    physics over the batch (rows = batch × n_out, columns = trainable parameters),
    ``g`` stacks the per-sample loss gradients ``∂/∂y_i ½‖y_i − y*_i‖² = y_i − y*_i``.
    Singular values ``σ ≤ τ · σ_max`` are *dropped* (their directions get no
    update), never clamped. ``e = −½`` is the half-inverse of the paper; ``e = −1``
    with η = 1 is the Gauss–Newton step ``−J⁺ g`` (hence ``g`` is the per-sample
    residual, not divided by the batch size: GN does not depend on the loss scale).
    The update replaces the optimizer (a plain step, as in the reference code).

    Jacobian (``jacobian=``, all with ``torch.func`` over ``functional_call``):

    * ``"forward"``: ``∂x_i/∂θ`` by ``vmap(jacrev(f))``, then ONE forward physics call
      on all ``B · n_params`` Jacobian columns;
    * ``"reverse"``: ``vmap(jacrev(P ∘ f))``, i.e. ONE adjoint physics call on
      ``B · n_out`` unit cotangents, then the network's vector-Jacobian products;
    * ``"auto"``: the route with fewer physics columns (reverse unless the network
      has fewer parameters than observations) — identical results, the physics cost
      differs by the factor ``n_params / n_out``.

    Decomposition (``route=``; recorded in ``info["route"]``):

    * ``"svd"``: float64 thin SVD of ``J``;
    * ``"gram"``: float64 ``eigh(J Jᵀ) = U Λ² Uᵀ``, update ``−η Jᵀ U Λ^(e−1) Uᵀ g``
      (``V = Jᵀ U Λ⁻¹``): ~10–20× faster when rows ≪ parameters (DESIGN.md), but
      squaring doubles the condition number's exponent, so small kept σ lose
      accuracy (relative error ≈ 2e-16 · cond²);
    * ``"randomized"``: matrix-free, ``J`` is never formed: a rank-``probes``
      randomized SVD from ``jvp``/``vjp`` products with ``power_iters`` power
      iterations (:mod:`pdeinv.methods.hig_randomized`); exact when
      ``rank(J) ≤ probes``, else the step lives in the top-``probes`` singular
      subspace (``info["rank_limited"]`` says when the cap, not τ, cut the spectrum);
    * ``"auto"``: ``gram`` when rows ≤ parameters and the kept part's condition
      number ``σ_max/σ_min,kept`` is at most ``gram_cond_max`` (1e6: relative error
      ≲ 2e-4 in the smallest kept direction), else ``svd`` (recorded as
      ``"svd"``; ``info["gram_rejected"]`` says the Gram route was tried first);
      when the dense Jacobian would exceed ``max_jacobian_gb``, ``randomized``.

    ``scale_step`` lowers the effective η in the state (checkpointed with it).
    A route whose memory exceeds ``max_jacobian_gb`` is refused with a
    ``ValueError`` before anything is computed. The randomized probes are drawn
    from ``SeedSequence([seed, step])``, so a resumed run repeats them.
    """

    eta: float = 1.0
    tau: float = 1e-6
    exponent: float = -0.5
    route: str = "auto"
    jacobian: str = "auto"
    max_jacobian_gb: float = 4.0
    gram_cond_max: float = 1e6
    probes: int = 128
    power_iters: int = 1
    seed: int = 0
    name: str = "hig"

    def __post_init__(self):
        positive(self.eta, "eta")
        nonnegative(self.tau, "tau")
        if not self.tau < 1:
            raise ValueError(f"tau={self.tau!r} is not allowed; expected 0 <= tau < 1 "
                             "(relative to the largest singular value)")
        choice(self.route, "route", ("auto", "svd", "gram", "randomized"))
        count(self.probes, "probes")
        count(self.power_iters, "power_iters", minimum=0)
        choice(self.jacobian, "jacobian", ("auto", "forward", "reverse"))
        positive(self.max_jacobian_gb, "max_jacobian_gb")

    def init(self, problem, model: torch.nn.Module) -> HIGState:
        return HIGState(problem.operator)

    def step(self, state: HIGState, model: torch.nn.Module, y_target: torch.Tensor):
        op = state.operator
        names = [n for n, p in model.named_parameters() if p.requires_grad]
        params = {n: p.detach() for n, p in model.named_parameters() if p.requires_grad}
        frozen = {n: p.detach() for n, p in model.named_parameters() if not p.requires_grad}
        frozen.update(dict(model.named_buffers()))
        n_params = sum(p.numel() for p in params.values())
        B = y_target.shape[0]
        rows = B * op.n_out
        jac_route = self.jacobian
        if jac_route == "auto":
            jac_route = "reverse" if op.n_out <= n_params else "forward"
        route = self._check_memory(B, op, rows, n_params, jac_route)

        def f(p, y):
            return functional_call(model, (p, frozen), (y,))

        with torch.no_grad():
            x = f(params, y_target)
            check_finite("the network output x = f(y*)", x)
            y = apply(op, x)
        r = (y - y_target).double()
        loss = 0.5 * float(r.pow(2).sum(-1).mean())
        check_finite("the y-loss", torch.tensor(loss))

        if route == "randomized":
            seed = int(np.random.SeedSequence([self.seed, state.steps]).generate_state(1)[0])
            delta, info = randomized_direction(model, op, y_target, r.reshape(rows), self.probes,
                                               self.power_iters, self.tau, self.exponent,
                                               self.eta * state.scale, seed)
            jac_route = "matrix-free"
        elif jac_route == "reverse":
            jac = vmap(jacrev(lambda p, yi: apply(op, f(p, yi))), in_dims=(None, 0))(params, y_target)
            J = torch.cat([jac[n].reshape(B, op.n_out, -1) for n in names], -1)
        else:
            jac = vmap(jacrev(f), in_dims=(None, 0))(params, y_target)
            Jx = torch.cat([jac[n].reshape(B, op.n_in, -1) for n in names], -1)  # (B, n_in, P)
            del jac
            cols = apply(op, Jx.transpose(1, 2).reshape(B * n_params, op.n_in))
            J = cols.reshape(B, n_params, op.n_out).transpose(1, 2)
        if route != "randomized":
            J = J.reshape(rows, n_params).double()
            check_finite("the HIG Jacobian", J)
            delta, info = self._direction(J, r.reshape(rows), rows, n_params, self.eta * state.scale)
        check_finite("the HIG update", delta)
        with torch.no_grad():
            offset = 0
            for n in names:
                p = model.get_parameter(n)
                p.add_(delta[offset:offset + p.numel()].view_as(p).to(p.dtype))
                offset += p.numel()
        info.update(loss=loss, jacobian=jac_route)
        return state._replace(steps=state.steps + 1), info

    def state_dict(self, state: HIGState) -> dict:
        return {"steps": state.steps, "scale": state.scale}

    def load_state_dict(self, state: HIGState, sd: dict) -> HIGState:
        return state._replace(steps=int(sd["steps"]), scale=float(sd["scale"]))

    def scale_step(self, state: HIGState, factor: float) -> HIGState:
        """The effective η becomes ``η · scale · factor`` (the rule object stays immutable)."""
        return state._replace(scale=state.scale * factor)

    def _direction(self, J, g, rows, n_params, eta: float | None = None):
        """``−η V Λ^e Uᵀ g`` over the kept singular values, and what was used.

        The products with ``J`` run in torch (float64, torch's thread setting);
        the decompositions in numpy's LAPACK: with torch 2.13's MKL on 2 cores,
        ``eigh`` and ``svd`` of a 248×3103 problem took 0.2 s and 0.3–6.7 s (first
        call), numpy 0.03 s and 0.2 s.
        """
        eta = self.eta if eta is None else eta
        info = {}
        if self.route == "gram" or (self.route == "auto" and rows <= n_params):
            lam2, U = np.linalg.eigh((J @ J.T).numpy())
            s = np.sqrt(lam2.clip(min=0))
            keep = (s > self.tau * s.max()) & (s > 0)
            cond = float(s.max() / s[keep].min())
            if self.route == "gram" or cond <= self.gram_cond_max:
                Uk, sk = U[:, keep], s[keep]
                coef = torch.from_numpy(Uk @ (sk ** (self.exponent - 1) * (Uk.T @ g.numpy())))
                return -eta * (J.T @ coef), dict(route="gram", rank=int(keep.sum()), cond=cond)
            info["gram_rejected"] = cond
        U, s, Vt = np.linalg.svd(J.numpy(), full_matrices=False)
        keep = (s > self.tau * s[0]) & (s > 0)
        Uk, sk, Vk = U[:, keep], s[keep], Vt[keep]
        delta = -eta * (Vk.T @ (sk ** self.exponent * (Uk.T @ g.numpy())))
        info.update(route="svd", rank=int(keep.sum()), cond=float(s[0] / sk.min()))
        return torch.from_numpy(delta), info

    def _check_memory(self, B, op, rows, n_params, jac_route) -> str:
        """The route to take (``"randomized"`` or a dense one); refuses one over the budget."""
        budget = self.max_jacobian_gb * 2**30
        sketch = memory_bytes(n_params, min(self.probes, rows, n_params), rows)
        if self.route == "randomized":
            route, need = "randomized", sketch
        else:
            route = self.route if self.route != "auto" else ("gram" if rows <= n_params else "svd")
            need = rows * n_params * _BYTES[route]
            if jac_route == "forward":
                need += B * op.n_in * n_params * 4 + B * n_params * op.n_out * 8  # ∂x/∂θ + physics copy
            if need > budget and self.route == "auto" and sketch <= budget:
                return "randomized"
        if need > budget:
            also = (f" (the matrix-free route: {sketch / 2**30:.1f} GB with probes={self.probes})"
                    if self.route == "auto" else "")
            raise ValueError(
                f"HIG Jacobian of {rows} rows (batch {B} × {op.n_out} observations) × {n_params} "
                f"parameters needs about {need / 2**30:.1f} GB with route {route!r}{also}, above "
                f"max_jacobian_gb={self.max_jacobian_gb:g}; use a smaller batch_size or network "
                "(fewer parameters), or raise max_jacobian_gb")
        return route
