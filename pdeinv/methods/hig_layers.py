"""HIG's layer-wise Kronecker route for dense networks not linear in θ (MLPs): ``J`` is never formed.

For ``x_i = D f(y_i)`` with ``f = W_L σ(… σ(W_1 h_0(y_i)) …)`` (an ``nn.Sequential`` of ``nn.Linear``
and elementwise activations, behind a fixed input map ``h_0`` and a fixed linear output map ``D``:
:class:`pdeinv.MLP`, :func:`pdeinv.nets.dense`, or a :class:`~pdeinv.nets.Net` with such a body),
let ``W̃_ℓ = [W_ℓ b_ℓ]`` and ``h̃_{i,ℓ−1} = [h_{i,ℓ−1}; 1]`` (the layer's input with a 1 appended).
With ``P̂ = P D = Q_C diag(s) Vᵀ`` (:func:`pdeinv.inverse.decoder.decoded_svd`, once per run), sample
i's Jacobian of ``y_i`` with respect to ``vec W̃_ℓ`` (row-major) is

    J_{i,ℓ} = Q_C E_{i,ℓ} ⊗ h̃_{i,ℓ−1}ᵀ,     E_{i,ℓ} = diag(s) Vᵀ ∂f_i/∂a_{i,ℓ}   (k × n_ℓ)

(``a_{i,ℓ} = W̃_ℓ h̃_{i,ℓ−1}``, the pre-activation; ``∂f_i/∂a_{i,L} = I``). ``Q_C`` has orthonormal
columns, so it changes no singular value, and the residual enters only as ``ρ_i = Q_Cᵀ r_i``.

**What is approximated.** HIG's step is ``Δθ = −η V_J Σ^e U_Jᵀ g = −η (JᵀJ)^((e−1)/2) Jᵀ g`` on the
kept subspace (:class:`~.hig.HIG`). This route replaces ``JᵀJ`` by

1. its **block diagonal across layers**, ``⊕_ℓ J_ℓᵀJ_ℓ`` (the layers' cross terms are dropped: each
   layer takes the step it would take alone), and
2. within each **hidden** layer the **Kronecker factorization** (K-FAC's, Martens & Grosse 2015)

       J_ℓᵀJ_ℓ = Σ_i (E_iᵀE_i) ⊗ (h̃_i h̃_iᵀ)  ≈  Ḡ_ℓ ⊗ A_ℓ,   Ḡ_ℓ = (1/B) Σ_i E_iᵀE_i,   A_ℓ = H̃ᵀH̃,

   exact when ``E_iᵀE_i`` is the same for every sample. ``Ḡ_ℓ`` is computed exactly (no sampling):
   ``K_{i,L} = V diag(s²) Vᵀ`` and ``K_{i,ℓ} = diag(σ'_i) W_{ℓ+1}ᵀ K_{i,ℓ+1} W_{ℓ+1} diag(σ'_i)``
   (``B`` products of ``n × n`` matrices per layer; ``Ḡ_{L−1} = (W_LᵀK W_L) ⊙ mean_i σ'_i σ'_iᵀ``).

For the **last layer** ``E_{i,L} = diag(s) Vᵀ`` does not depend on i, so (2) is exact: its block is
``(V diag(s²) Vᵀ) ⊗ (H̃ᵀH̃)``, hig_kron's algebra (:mod:`.hig_kron`) with the hidden features as
``Z̃``, and its step *is* hig_kron's exact step given those features. A network with one trainable
``nn.Linear`` (or all others frozen) therefore gets HIG's exact step (``tests/test_hig_layers.py``).

Per layer, with ``Ḡ = Q_G diag(γ) Q_Gᵀ`` and ``A = Q_A diag(α) Q_Aᵀ`` (float64; ``A``'s nonzero
eigenpairs from the ``B × B`` ``H̃H̃ᵀ`` when the batch is smaller than the layer's input), the
approximated ``J``'s singular values are ``σ_ab = √(γ_a α_b)`` over all layers, and

    ΔW̃_ℓ = −η Q_G [(Q_Gᵀ ∇_ℓ Q_A) ⊙ S] Q_Aᵀ,   S_ab = σ_ab^(e−1) if σ_ab > τ·σ_max else 0,

``∇_ℓ = Σ_i δ_{i,ℓ} h̃_{i,ℓ−1}ᵀ = J_ℓᵀ g`` (back-propagation of ``P̂ᵀ r_i``). ``σ_max`` is the largest
over all layers (the block-diagonal matrix's), so the τ drop and ``normalize``'s ``σ_max^-(1+e)``
(applied by :class:`~.hig.HIG`) are those of the approximated ``JᵀJ``. A frozen layer takes no step
but is back-propagated through. Because the blocks' cross terms are dropped, the layers' steps add up
in the residual: along a direction all layers see, the step can move the residual by more than the
exact HIG step (at most the sum over layers of what each moves alone).

Cost per step: one float64 forward and backward pass of the network, ``B`` products of ``n_ℓ × n_ℓ``
matrices per hidden layer, eigendecompositions of ``n_ℓ × n_ℓ`` and ``min(B, n_{ℓ−1}+1)²`` matrices;
no physics beyond the residual :class:`~.hig.HIG` computes.

Measured: see ``benchmarks/hig_mlp.py`` (table below, filled from its output).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from ..inverse.decoder import DecodedSVD, decoded_svd
from .hig_kron import rank

#: the elementwise activations the route differentiates (their derivative is a diagonal)
ELEMENTWISE = (nn.Tanh, nn.ReLU, nn.Sigmoid, nn.GELU, nn.SiLU, nn.Softplus, nn.ELU, nn.LeakyReLU,
               nn.Identity)

SUPPORTED = ("pdeinv.MLP, pdeinv.nets.dense (an nn.Sequential of nn.Linear layers and elementwise "
             f"activations ({', '.join(c.__name__ for c in ELEMENTWISE)}) ending in nn.Linear), or a "
             "pdeinv.nets.Net with such a body and no trainable parameter outside it")


class Layers(NamedTuple):
    """A network as this route sees it: ``x = D f(features(y))``, ``f`` alternating ``linears`` and the
    elementwise ``between[ℓ]`` after ``linears[ℓ]``; ``names[ℓ]``: the model's names of the layer's
    (weight, bias) parameters; ``decoder``: the rows ``Dᵀ`` or ``None``."""

    features: object
    linears: tuple
    between: tuple
    names: tuple
    decoder: torch.Tensor | None


def layers(model: nn.Module) -> Layers:
    """``model`` as :class:`Layers`; ``ValueError`` naming what is supported for any other network."""
    from ..nets import MLP, Net

    decoder = None
    if isinstance(model, MLP):
        body = model.body
        features = lambda y: (y.double() - model.shift.double()) / model.scale.double()  # noqa: E731
    elif isinstance(model, Net):
        if not isinstance(model.post, nn.Identity) and model.decoder is None:
            _refuse(model, f"its output map {type(model.post).__name__} is not a fixed decoder")
        body, decoder = model.body, model.decoder
        features = lambda y: model.pre(y.to(_dtype(model))).double()  # noqa: E731
    elif isinstance(model, nn.Sequential):
        body, features = model, lambda y: y.double()  # noqa: E731
    else:
        _refuse(model, "it is not one of them")
    mods = list(body) if isinstance(body, nn.Sequential) else [body]
    lead = []
    while mods and not isinstance(mods[0], nn.Linear):  # leading activations: part of the fixed map
        lead.append(mods.pop(0))
    if not mods or not isinstance(mods[-1], nn.Linear):
        _refuse(model, "its body does not end in an nn.Linear")
    linears, between = [], []
    for m in mods:
        if type(m) is nn.Linear:
            linears.append(m)
            between.append([])
        elif isinstance(m, ELEMENTWISE):
            between[-1].append(m)
        else:
            _refuse(model, f"its body holds a {type(m).__name__}")
    names_of = {id(p): n for n, p in model.named_parameters()}
    in_layers = {id(p) for m in linears for p in m.parameters()}
    outside = [n for n, p in model.named_parameters() if p.requires_grad and id(p) not in in_layers]
    if outside:
        _refuse(model, f"its trainable parameters {', '.join(outside)} are outside its nn.Linear layers")
    for m in linears:
        if len({p.requires_grad for p in m.parameters()}) > 1:
            _refuse(model, "one of its nn.Linear layers is partly frozen (freeze weight and bias together)")
    names = tuple(tuple(names_of[id(p)] for p in (m.weight, m.bias) if p is not None) for m in linears)
    fixed = nn.Sequential(*lead)
    return Layers(lambda y: fixed(features(y)), tuple(linears), tuple(tuple(b) for b in between), names, decoder)


def _dtype(model: nn.Module) -> torch.dtype:
    return next(iter(model.parameters()), torch.empty((), dtype=torch.float64)).dtype


def _refuse(model, why: str):
    raise ValueError(f"HIG(route='layers') supports {SUPPORTED}; {type(model).__name__} is not supported: {why}")


def direction(net: Layers, fac: DecodedSVD, y: torch.Tensor, r: np.ndarray, params: dict, eta: float,
              tau: float, exponent: float) -> tuple[dict, dict]:
    """``{parameter name: step}`` for the trainable layers and what was kept (module docstring), from the
    batch's observations ``y`` and residuals ``r`` (``B × m``, float64, in ``fac``'s output coordinates).
    The step is unnormalized: :class:`~.hig.HIG` multiplies it by ``σ_max^-(1+e)``."""
    hs, ds = _forward(net, y)
    last = len(net.linears) - 1
    trainable = [next(iter(m.parameters())).requires_grad for m in net.linears]
    low = min((ell for ell in range(last + 1) if trainable[ell]), default=last + 1)  # deepest trained
    Ws = [m.weight.detach().cpu().double().numpy() for m in net.linears]
    Vs = fac.V * fac.s  # P̂ᵀ = V diag(s) Q_Cᵀ
    # δ_L = P̂ᵀ r_i in the output coordinates, back-propagated: δ_ℓ = (δ_{ℓ+1} W_{ℓ+1}) ⊙ σ'_ℓ
    delta = {last: (r @ fac.Q) @ Vs.T}
    # output-side factors (Q_G, γ): the last layer's exactly from P̂'s SVD, the hidden ones from K̄_ℓ
    sides = {last: (fac.V, fac.s**2)}
    K = None
    for ell in range(last - 1, low - 1, -1):
        delta[ell] = (delta[ell + 1] @ Ws[ell + 1]) * ds[ell]
        if K is None:  # the layer below the output: K_i = diag(σ'_i) (W_Lᵀ P̂ᵀP̂ W_L) diag(σ'_i)
            M = Vs.T @ Ws[last]
            K = (M.T @ M)[None] * ds[ell][:, :, None] * ds[ell][:, None, :]
        else:
            K = np.einsum("ja,bjk,kc->bac", Ws[ell + 1], K, Ws[ell + 1], optimize=True)
            K *= ds[ell][:, :, None] * ds[ell][:, None, :]
        if trainable[ell]:
            gamma, QG = np.linalg.eigh(K.mean(0))
            keep = gamma > gamma[-1] * len(gamma) * np.finfo(float).eps if gamma[-1] > 0 else gamma > 1
            sides[ell] = (QG[:, keep], gamma[keep])
    H_of = hs
    inputs = {ell: _input_side(hs[ell]) for ell in range(low, last + 1) if trainable[ell]}
    smax = max((float(np.sqrt(sides[ell][1].max() * inputs[ell][0].max())) for ell in inputs
                if sides[ell][1].size and inputs[ell][0].size), default=0.0)
    steps, kept, smin = {}, 0, np.inf
    for ell, (alpha, L, R) in inputs.items():
        QG, gamma = sides[ell]
        sigma = np.sqrt(gamma[:, None] * alpha[None, :])
        import os
        th = float(os.environ.get("HL_TAUH", tau)) if ell != last else tau
        keep = sigma > th * smax if smax > 0 else np.zeros_like(sigma, bool)
        S = np.zeros_like(sigma)
        S[keep] = sigma[keep] ** (exponent - 1.0)
        kept += int(keep.sum())
        smin = min(smin, float(sigma[keep].min())) if keep.any() else smin
        step = -eta / float(os.environ.get("HL_DIV", 1)) * (QG @ (((delta[ell] @ QG).T @ L) * S)) @ R  # −η Q_G [(Q_Gᵀ ∇ Q_A) ⊙ S] Q_Aᵀ
        if ell != last and os.environ.get("HL_HIDDEN") == "gd" and gamma.size and alpha.size:
            step = -float(os.environ.get("HL_ETA", 1.0)) * delta[ell].T @ H_of[ell] * smax ** (1 + exponent) / (gamma.max() * alpha.max())
        steps.update(_split(net, ell, step, params))
    return steps, {"route": "layers", "kept": kept, "sigma_max": smax,
                   "sigma_min_kept": smin if kept else 0.0}


def _input_side(H: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(α, L, R)`` for ``A = H̃ᵀH̃ = Q_A diag(α) Q_Aᵀ`` (nonzero part) with ``∇ Q_A = Δᵀ L`` and
    ``Q_Aᵀ = R`` (``∇ = Δᵀ H̃``): from the ``B × B`` row Gram ``H̃H̃ᵀ = U diag(α) Uᵀ`` when the batch
    has fewer rows than ``H̃`` has columns (``Q_A = H̃ᵀ U α^-½``: ``L = U α^½``, ``R = α^-½ Uᵀ H̃``),
    else from ``A`` itself (``L = H̃ Q_A``, ``R = Q_Aᵀ``)."""
    if H.shape[0] < H.shape[1]:
        a, U = rank(*np.linalg.eigh(H @ H.T), H.shape)
        root = np.sqrt(a)
        return a, U * root, (U / root).T @ H
    a, QA = rank(*np.linalg.eigh(H.T @ H), H.shape)
    return a, H @ QA, QA.T


def _forward(net: Layers, y: torch.Tensor) -> tuple[list, list]:
    """Float64 ``(H̃_ℓ, σ'_ℓ)``: each layer's input with a column of ones (when it has a bias) and the
    derivative of the elementwise maps after it (``B × n_ℓ``; autograd of their sum: elementwise)."""
    with torch.no_grad():
        h = net.features(y.detach()).double()
    hs, ds = [], []
    for ell, m in enumerate(net.linears):
        with torch.no_grad():
            H = h if m.bias is None else torch.cat([h, torch.ones(len(h), 1, dtype=h.dtype, device=h.device)], 1)
            hs.append(H.cpu().numpy())
        if ell == len(net.linears) - 1:
            break
        with torch.no_grad():
            a = H @ _weight(m).T
        a.requires_grad_(True)
        with torch.enable_grad():
            out = a
            for act in net.between[ell]:
                out = act(out)
        d = torch.autograd.grad(out.sum(), a)[0] if out is not a else torch.ones_like(a)
        ds.append(d.detach().cpu().numpy())
        h = out.detach()
    return hs, ds


def _weight(m: nn.Linear) -> torch.Tensor:
    """``W̃ = [W b]`` in float64 (``W`` without a bias)."""
    w = m.weight.detach().double()
    return w if m.bias is None else torch.cat([w, m.bias.detach().double()[:, None]], 1)


def _split(net: Layers, ell: int, step: np.ndarray, params: dict) -> dict:
    """``ΔW̃_ℓ`` as ``{name: tensor}`` for the layer's weight and bias."""
    m, names = net.linears[ell], net.names[ell]
    parts = {names[0]: step[:, : m.in_features]}
    if m.bias is not None:
        parts[names[1]] = step[:, -1]
    return {n: torch.from_numpy(np.ascontiguousarray(v)) for n, v in parts.items() if n in params}
