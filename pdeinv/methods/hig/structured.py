"""HIG's exact step for dense networks (MLPs) from their layer structure: ``J`` without ``torch.func``.

For a network of :func:`.hig_layers.body` (``nn.Linear`` layers and elementwise activations behind a
fixed input map, before a fixed decoder ``D``), with ``P̂ = P D = Q_C diag(s) Vᵀ``
(:func:`pdeinv.inverse.decoder.decoded_svd`, once per run), sample i's Jacobian rows with respect to
layer ℓ's ``W̃_ℓ = [W_ℓ b_ℓ]`` are, in the coordinates ``Q_Cᵀ y`` (``Q_C`` changes no singular value
and ``Q_Cᵀ r_i`` is all of the residual any step can change),

    J_{i,ℓ} = E_{i,ℓ} ⊗ h̃_{i,ℓ−1}ᵀ,   E_{i,L} = diag(s) Vᵀ,   E_{i,ℓ} = (E_{i,ℓ+1} W_{ℓ+1}) diag(σ'(a_{i,ℓ}))

(``h̃``: the layer's input with a 1 appended, ``a``: its pre-activation; the last line is
back-propagation of the ``k`` rows of ``diag(s)Vᵀ``). Nothing is approximated: this is the
stacked ``J`` of :class:`~.hig.HIG`, ``B·k`` rows. Its Gram needs no ``J``,

    J Jᵀ = Σ_ℓ (E_ℓ E_ℓᵀ) ⊙ ((H̃_ℓ H̃_ℓᵀ) ⊗ 𝟙_{k×k})     (E_ℓ: the ``B·k × n_ℓ`` stacked rows)

at ``(B·k)² n_ℓ`` per layer instead of ``(B·k)² · n_params``, and the step ``−η Jᵀ U Λ^(e−1) Uᵀ g``
is ``ΔW̃_ℓ = −η Σ_i E_{i,ℓ}ᵀ c_i h̃_{i,ℓ−1}ᵀ`` with ``c = U Λ^(e−1) Uᵀ g`` (the Gram route of
:mod:`.hig_routes`, the same τ drop, condition-number guard and ``info``). When the Gram is
refused (kept condition number above ``gram_cond_max``) or the rows outnumber the parameters,
``J`` itself is formed from the same factors and decomposed by the SVD route. Equal to the dense
routes to float64 rounding (``tests/test_hig_layers.py``); the trainable layers' order is the
model's.

Why: ``torch.func``'s ``J Jᵀ`` costs ``(B·k)² · n_params``; on heat_1d with an MLP (64, 64) this is ~14×
faster per step (``benchmarks/hig_mlp.py``).
"""

from __future__ import annotations

import numpy as np
import torch

from ...inverse.decoder import DecodedSVD
from . import layers as hig_layers


class Rows:
    """A batch's Jacobian factors: per layer the stacked ``E_ℓ`` (``B × k × n_ℓ``) and ``H̃_ℓ``
    (``B × (n_{ℓ−1}+1)``, no column of ones without a bias), for the trainable layers; ``g``: the
    residual ``Q_Cᵀ r_i`` stacked (``B·k``)."""

    def __init__(self, model, fac: DecodedSVD, y: torch.Tensor, R: np.ndarray, trainable: set):
        before, mods, _ = hig_layers.body(model, "auto")
        h = y.detach() if before is None else before(y.detach())
        h = h.double()
        linears = [m for m in mods if isinstance(m, torch.nn.Linear)]
        inputs, derivs = [], []
        for m in mods:  # float64 forward: each layer's input, the derivative of the maps after it
            if isinstance(m, torch.nn.Linear):
                inputs.append(h)
                h = h @ m.weight.detach().double().T + (0 if m.bias is None else m.bias.detach().double())
                derivs.append(torch.ones_like(h))
                continue
            a = h.detach().requires_grad_(True)
            with torch.enable_grad():
                out = m(a)
            if derivs:  # elementwise: the derivative is the gradient of the sum (a diagonal)
                derivs[-1] = derivs[-1] * torch.autograd.grad(out.sum(), a)[0]
            h = out.detach()
        self.k, self.B = len(fac.s), len(y)
        E = torch.from_numpy((fac.V * fac.s).T.copy())[None].expand(self.B, -1, -1)  # diag(s) Vᵀ
        self.layers = []  # (layer, E_ℓ, H̃_ℓ) for the trainable ones, output first
        for ell in range(len(linears) - 1, -1, -1):
            m = linears[ell]
            if id(m.weight) in trainable:
                ones = torch.ones(self.B, 1, dtype=torch.float64)
                H = inputs[ell] if m.bias is None else torch.cat([inputs[ell], ones], 1)
                self.layers.append((m, E, H))
            if ell and any(id(q.weight) in trainable for q in linears[:ell]):
                E = (E @ m.weight.detach().double()) * derivs[ell - 1][:, None, :]
        self.g = torch.from_numpy(np.ascontiguousarray(R @ fac.Q)).reshape(-1)

    def gram(self) -> torch.Tensor:
        """``J Jᵀ`` (module docstring), ``B·k × B·k``."""
        n = self.B * self.k
        out = torch.zeros(n, n, dtype=torch.float64)
        for _, E, H in self.layers:
            X = E.reshape(n, -1)
            out += (X @ X.T) * (H @ H.T).repeat_interleave(self.k, 0).repeat_interleave(self.k, 1)
        return out

    def transpose_times(self, c: torch.Tensor) -> dict:
        """``Jᵀ c`` per trainable layer: ``{layer: Σ_i E_iᵀ c_i h̃_iᵀ}`` (``n_ℓ × (n_{ℓ−1}+1)``)."""
        C = c.reshape(self.B, self.k)
        return {m: torch.einsum("ikn,ik->in", E, C).T @ H for m, E, H in self.layers}

    def jacobian(self) -> dict:
        """``J`` per trainable layer, ``{layer: (B·k) × n_ℓ × (n_{ℓ−1}+1)}`` (the SVD fallback)."""
        return {m: torch.einsum("ikn,ia->ikna", E, H).reshape(self.B * self.k, E.shape[2], H.shape[1])
                for m, E, H in self.layers}
