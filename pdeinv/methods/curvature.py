"""The scale of a least-squares loss in a network's parameters: the largest Gauss–Newton eigenvalue.

For ``L(θ) = ½ · mean_i ‖f(y_i; θ) − t_i‖²`` (SIP's proxy loss) the Gauss–Newton matrix is

    G = (1/B) Jᵀ J,      J = ∂ vec f(y_1..B; θ) / ∂θ,

exactly the Hessian when ``f`` is linear in ``θ`` (the whitened linear default network). Plain
gradient descent on ``L`` is stable for a step ``< 2/λ_max(G)`` and ``1/λ_max(G)`` is the classic
Landweber step (Engl, Hanke, Neubauer, *Regularization of Inverse Problems*, §6.1). λ_max is found
by power iteration on ``v ↦ Jᵀ(J v)/B`` with ``torch.func.jvp`` and ``torch.func.vjp`` (``J`` is never
formed); the Rayleigh quotient after ``iters`` iterations is a lower bound, within a few percent of
λ_max for the batch spectra of whitened inputs (a Marchenko–Pastur bulk), well inside the factor 2
that stability allows. Deterministic: the start vector comes from a generator seeded with ``seed``.

For GD's loss ``½ · mean_i ‖P f(y_i; θ) − y*_i‖²`` the Gauss–Newton matrix is ``(1/B) JᵀPᵀPJ``; for
a network linear in ``θ`` it is the Kronecker product ``(Z̃ᵀZ̃/B) ⊗ PᵀP``, so its largest eigenvalue
is ``λ_max(PᵀP) · gauss_newton_max(f)`` exactly, and an upper bound for any other network
(:func:`operator_norm2` gives ``λ_max(PᵀP)``).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch.func import functional_call, jvp, vjp

from ..errors import NonFiniteError


def checked(lam: float, what: str) -> float:
    """``lam`` if it is a usable curvature; a non-finite one (the network's output or parameters are
    not finite) is a :class:`NonFiniteError` like any other, a zero one a ``ValueError``."""
    if not math.isfinite(lam):
        raise NonFiniteError(f"{what} on the first batch is not finite ({lam}): the network's output or "
                             "parameters are not finite; nothing was applied")
    if not lam > 0:
        raise ValueError(f"{what} on the first batch is {lam!r}; expected a number > 0 (does the "
                         "network depend on its parameters?)")
    return lam


def gauss_newton_max(model: torch.nn.Module, y: torch.Tensor, iters: int = 30, seed: int = 0,
                     diagonal: tuple[torch.Tensor, ...] | None = None) -> float:
    """``λ_max((1/B) JᵀJ)`` of ``model`` at its current parameters on the batch ``y`` ``(B, ·)``; with
    ``diagonal`` (one positive tensor per trainable parameter, ``d``) that of the Jacobi-preconditioned
    ``d^{-1/2} G d^{-1/2}`` (same eigenvalues as ``d⁻¹G``, the matrix a step ``−lr·d⁻¹∇L`` iterates)."""
    params = {k: p.detach() for k, p in model.named_parameters() if p.requires_grad}
    root = {k: torch.ones((), dtype=torch.float64) for k in params} if diagonal is None else \
        {k: d.double().rsqrt() for k, d in zip(params, diagonal, strict=True)}
    if not params:
        raise ValueError("the model has no trainable parameters")
    frozen = {**{k: p.detach() for k, p in model.named_parameters() if not p.requires_grad},
              **dict(model.named_buffers())}
    batch = y.shape[0]

    def f(p):
        return functional_call(model, {**frozen, **p}, (y,))

    _, pullback = vjp(f, params)
    gen = torch.Generator().manual_seed(seed)
    v = {k: torch.randn(p.shape, generator=gen, dtype=torch.float64) for k, p in params.items()}
    lam = 0.0
    for _ in range(iters):
        norm = math.sqrt(sum(float((t.double() ** 2).sum()) for t in v.values()))
        if not norm > 0:
            return lam
        v = {k: t / norm for k, t in v.items()}
        _, jv = jvp(f, (params,), ({k: (t * root[k]).to(params[k]) for k, t in v.items()},))
        (w,) = pullback(jv)
        w = {k: t.double() * root[k] / batch for k, t in w.items()}
        lam = sum(float((w[k].double() * v[k].double()).sum()) for k in v)  # Rayleigh quotient
        v = w
    return lam


def operator_norm2(op, iters: int = 30, seed: int = 0) -> float:
    """``λ_max(PᵀP)`` of a linear operator (Euclidean, as GD's loss): ``max g²`` of a spectral basis in
    Euclidean coordinates is not that (its norms are the mass matrices'), so always by power
    iteration on ``forward``/``adjoint`` (numpy, one column), a lower bound within a few percent.
    Through ``jvp``/``vjp`` at ``x = 0``, which for a linear operator are ``forward``/``adjoint``; for a
    nonlinear one it is ``λ_max`` of the tangent at 0, the output of a network whose last layer
    starts at zero (the first batch's curvature, as for the network's factor)."""
    v = np.random.default_rng(seed).standard_normal((1, op.n_in))
    x = np.zeros_like(v)
    lam = 0.0
    for _ in range(iters):
        v /= np.linalg.norm(v)
        w = op.vjp(x, op.jvp(x, v))
        lam = float((w * v).sum())
        v = w
    return lam
