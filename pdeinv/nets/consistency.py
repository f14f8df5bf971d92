"""Data consistency: the last layer of a refined network, which gives the observations back what a prior
correction took from them.

A correction fitted on prior draws (:mod:`pdeinv.nets.refine`) improves ``x`` where the physics is
silent, but nothing ties it to the observations: its estimate ``x_c`` no longer reproduces ``y``. In an
operator's spectral basis (``P = out diag(g) Inᵀ``: the modal heat backend, a compiled SVD;
:class:`pdeinv.physics.capabilities.Spectral`) the data give each mode's coefficient directly,
``d_k = (y proj)_k / g_k``, and the corrected estimate gives ``c_k = (x_c In)_k``. Per mode the layer
takes the least-squares blend of the two,

    x = x_c + synth (w ⊙ (d − c)),      w_k = argmin_w Σ_i ‖w d_ik + (1 − w) c_ik − c*_ik‖²
                                            = Σ_i (d_ik − c_ik)(c*_ik − c_ik) / Σ_i (d_ik − c_ik)²,

``c*`` the true coefficients of held-out prior draws, ``w`` clipped to [0, 1]. Noise-free, ``d = c*`` in
every mode the basis keeps, so ``w = 1`` and ``P x = y`` to the basis' tolerance; with noise, ``w_k`` is
the per-mode Wiener weight between the data (noise variance ``σ²/g_k²``) and the correction (its own
held-out error), so strong modes follow the data and modes below the noise keep the prior's guess: the
residual stays at the noise level. Components of ``x_c`` outside the basis (the modes the physics
destroys) are left alone: that is where the prior decides (null-space networks, Schwab, Antholzer &
Haltmeier 2019).

Before :meth:`DataConsistency.fit` the weights are Tikhonov's around ``x_c``, ``w = g²/(g² + α)`` with
``α = rel · max g²`` (``rel`` the squared noise level, or rounding), the proximal step on the data term.
The basis is rebuilt from the problem (not saved); the weights are saved with the model.

**The rule keeps what it resolves.** Given the rule's own estimate ``b`` (the base network), the modes the
data resolve are taken from ``b`` unchanged,

    f = x − synth_R ((x − b) In_R),      R = {k : g_k² ≥ α  and  w_k ≥ 1/2}:

the data's noise in the mode is below its signal scale (Tikhonov's filter factor at least 1/2) and, on
held-out draws, the data weigh more than the corrected estimate (the fitted weight; before a fit, the
Tikhonov weight, so the two conditions agree).

so the prior stage and this layer change only the modes the observations cannot decide (and those outside
the basis): a network trained by SIP keeps SIP's answer where the data decide, one trained by Adam keeps
Adam's. Where the rule fits the data (SIP: ``P b = y`` to the noise), ``f`` does too.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from .corrections import SpectralFilter


class DataConsistency(nn.Module):
    """``x ↦ x + synth (w ⊙ (y proj / g − x In))``, then the rule's modes from ``b`` (module docstring);
    float64 throughout."""

    def __init__(self, modes, rel_alpha: float):
        super().__init__()
        g = np.asarray(modes.g, dtype=float)
        alpha = rel_alpha * float(np.max(g**2)) if g.size else 0.0
        as64 = lambda a: torch.as_tensor(np.asarray(a, dtype=float))  # noqa: E731
        self.register_buffer("g", as64(g), persistent=False)
        self.register_buffer("In", as64(modes.In), persistent=False)
        self.register_buffer("proj", as64(modes.proj), persistent=False)
        self.register_buffer("synth", as64(modes.synth), persistent=False)
        den = g**2 + alpha  # 0 only where every gain is 0 (nothing observed): weight 0
        self.register_buffer("weight", as64(np.divide(g**2, den, out=np.zeros_like(g), where=den > 0)))
        self.register_buffer("resolved", as64(g**2) >= alpha, persistent=False)  # g² ≥ α, a part of R

    #: moves with its network (a device) but stays float64, as the filter does: ``1/g`` reaches the
    #: basis' tolerance
    _apply = SpectralFilter._apply

    def gaps(self, y: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(d − c, c)``: the data's coefficients minus ``x``'s, and ``x``'s, per mode ``(B, k)``."""
        c = x.to(self.In.dtype) @ self.In
        return (y.to(self.proj.dtype) @ self.proj) / self.g - c, c

    def forward(self, y: torch.Tensor, x: torch.Tensor, base: torch.Tensor | None = None) -> torch.Tensor:
        """The blend of ``x`` with the data; with the rule's estimate ``base``, its resolved modes kept."""
        gap, _ = self.gaps(y, x)
        # y's own rounding, relative to its largest mode, is noise the weights were not fitted on: a
        # float32 y damps modes below 100 ulps of max g (float64: beyond the basis' tolerance anyway)
        floor = (100 * torch.finfo(y.dtype).eps * self.g.abs().max()) ** 2
        w = self.weight * self.g**2 / (self.g**2 + floor)
        out = x.to(self.synth.dtype) + (w * gap) @ self.synth.T  # float64: y to rounding
        return out if base is None else self.keep_rule(out, base)

    def keep_rule(self, x: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
        """``x − synth_R ((x − b) In_R)``: ``x`` with the modes the data resolve taken from ``b``."""
        r = self.resolved & (self.weight >= 0.5)
        return x - ((x - base.to(x.dtype)) @ self.In[:, r]) @ self.synth[:, r].T

    @torch.no_grad()
    def fit(self, y, x_c, x) -> None:
        """Per-mode least-squares weights from held-out rows: observations ``y``, corrected estimates
        ``x_c`` and true fields ``x`` (tensors or arrays, ``(n, ·)``); modes the rows leave undecided
        (no gap at all) keep their Tikhonov weight."""
        t = lambda a: torch.as_tensor(a, dtype=self.In.dtype)  # noqa: E731
        gap, c = self.gaps(t(y), t(x_c))
        miss = t(x) @ self.In - c
        den = (gap * gap).sum(0)
        w = torch.where(den > 0, (gap * miss).sum(0) / torch.where(den > 0, den, 1.0), self.weight)
        self.weight.copy_(torch.nan_to_num(w, nan=0.0).clamp(0.0, 1.0))
