"""A nonlinear correction of a network's estimate, fitted on draws of the prior: what no linear
estimator can do.

Physics-based rules (GD, SIP, HIG) see ``x`` only through ``y = P x``: the part of ``x`` the physics
destroys (heat's fine scales below rounding, a sensor set's blind spots) receives no gradient, so a
network trained by them alone fills it with whatever its architecture implies, at best the linear
MMSE's Gaussian guess. Where the prior is not Gaussian (the SIP paper's boxes: jumps) the conditional
mean of those parts given the visible ones is nonlinear, and the only source of it is the prior
itself. :class:`Refined` is therefore

    f(y) = b(y) + E g(Ê b(y)),

``b`` the base network (trained by the rule, e.g. SIP: the whitened linear map or the prior
decoder), ``Ê``/``E`` the maps to and from a regular grid (:class:`~pdeinv.fem.grid.GridMap`), ``g`` a
U-Net (:class:`UNet`) whose last layer starts at zero, so ``f = b`` until the correction is fitted.
:meth:`Refined.fit_prior` fits ``g`` (``b`` frozen) after the rule, on prior draws ``(x, y)`` — the
scene's sampler, or the rows of the user's file that carry ``x`` (never the test rows):

    min_g  mean_i ‖b(y_i) + E g(Ê b(y_i)) − x_i‖²,

Adam, early-stopped on held-out draws; the correction is kept only if it lowers the held-out
relative L²(Ω) error (otherwise ``g`` stays zero and ``f = b``): never worse than the base on draws
from the prior. This is the post-processing design of learned reconstruction (Jin et al. 2017,
FBPConvNet), with the physics-trained ``b`` in place of a fixed classical inverse. Measured
(heat_boxes 64×64, ``pdeinv train heat_boxes``, SIP, one loaded thread): 0.173 → 0.052 noise-free
(best-α Tikhonov 0.135, linear MMSE 0.199), 0.330 → 0.162 at 1 % (0.320, 0.322); docs/results.md.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ..fem.grid import GridMap
from .protocol import Network, declared


def _conv(dim: int):
    return {1: nn.Conv1d, 2: nn.Conv2d, 3: nn.Conv3d}[dim]


class UNet(nn.Module):
    """A two-level U-Net ``g`` on ``dim``-dimensional images, ``c`` channels at full resolution
    (``2c``, ``4c`` below), GELU, skip connections, a zero-initialized 1×1 output: ``g ≡ 0`` at start.
    Parameters ~ ``60 c²·3^dim / 9``, independent of the mesh."""

    def __init__(self, dim: int, c: int = 16, channels_in: int = 1):
        super().__init__()
        Conv, act = _conv(dim), nn.GELU

        def block(a, b, stride=1):
            return nn.Sequential(Conv(a, b, 3, padding=1, stride=stride), act(),
                                 Conv(b, b, 3, padding=1), act())

        self.dim = dim
        self.e1, self.e2, self.e3 = block(channels_in, c), block(c, 2 * c, 2), block(2 * c, 4 * c, 2)
        self.u2 = nn.Sequential(Conv(6 * c, 2 * c, 3, padding=1), act())
        self.u1 = nn.Sequential(Conv(3 * c, c, 3, padding=1), act())
        self.out = Conv(c, 1, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, g: torch.Tensor) -> torch.Tensor:
        mode = {1: "linear", 2: "bilinear", 3: "trilinear"}[self.dim]
        up = lambda t, ref: F.interpolate(t, size=ref.shape[2:], mode=mode, align_corners=False)  # noqa: E731
        a = self.e1(g)
        b = self.e2(a)
        c = self.e3(b)
        d = self.u2(torch.cat([up(c, b), b], 1))
        return self.out(self.u1(torch.cat([up(d, a), a], 1)))


class SpectralFilter(nn.Module):
    """A fixed linear estimate from the physics alone, ``x_T = synth (g/(g² + α) ⊙ projᵀ y)`` in an
    operator's spectral basis (the modal heat backend): Tikhonov with ``α = rel·max g²``, nothing learned,
    full rank. Its buffers are not saved (rebuilt from the problem, deterministic)."""

    def __init__(self, modes, rel_alpha: float):
        super().__init__()
        g = np.asarray(modes.g, dtype=float)
        alpha = rel_alpha * float(np.max(g**2)) if g.size else 0.0
        self.register_buffer("proj", torch.as_tensor(np.asarray(modes.proj, dtype=float)), persistent=False)
        self.register_buffer("filt", torch.as_tensor(g / (g**2 + alpha)), persistent=False)
        self.register_buffer("synth", torch.as_tensor(np.asarray(modes.synth, dtype=float)), persistent=False)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        y = y.to(self.proj.dtype)
        return ((y @ self.proj) * self.filt) @ self.synth.T


@dataclass(frozen=True)
class PriorFit:
    """How :meth:`Refined.fit_prior` fits the correction: Adam at ``lr``, ``batch`` draws per step, at
    most ``steps`` steps or ``time_budget`` seconds, the held-out error checked every ``check_every``
    steps on ``held_out`` of the draws; stops after ``patience`` checks without a relative improvement
    of ``min_gain`` over the best so far (which is what is kept)."""

    steps: int = 4000
    time_budget: float | None = 300.0
    lr: float = 1e-3
    batch: int = 32
    held_out: float = 0.125
    check_every: int = 100
    patience: int = 5
    min_gain: float = 0.005
    seed: int = 0

    def applies(self, model) -> bool:
        """Whether ``model`` has a part fitted on prior draws (:class:`PriorFitted`)."""
        return isinstance(model, PriorFitted)

    def fit(self, model, x, y, relative_error, log=None) -> dict:
        """``model.fit_prior`` with these settings (:meth:`Refined.fit_prior`)."""
        return model.fit_prior(x, y, relative_error, self, log)


@runtime_checkable
class PriorFitted(Protocol):
    """A network with a part fitted on prior draws after the rule (:meth:`Refined.fit_prior`)."""

    def fit_prior(self, x, y, relative_error, settings: PriorFit = ..., log=None) -> dict: ...


class Refined(Network):
    """``f(y) = b(y) + E g(Ê b(y))`` (module docstring). Until :meth:`fit_prior` keeps a correction,
    ``f = b`` exactly and the base's declared structure (linear in its parameters, decoder,
    Gauss–Newton diagonal) is the network's: the rules train ``b`` as they would alone."""

    def __init__(self, base: nn.Module, grid: GridMap, channels: int = 16, dim: int | None = None,
                 physics: SpectralFilter | None = None):
        super().__init__()
        self.base, self.grid, self.physics = base, grid, physics
        inputs = 1 if physics is None else 2
        self.correction = UNet(dim or len(grid.shape), channels, inputs).to(torch.float32)
        self.correction.requires_grad_(False)  # trained by fit_prior only
        self.register_buffer("active", torch.zeros((), dtype=torch.bool))
        self.prior_info: dict = {}

    # --- the base's declared structure, valid while the correction is off -----------------------
    def fit_observations(self, y, noise=None, **settings):
        declared(self.base).fit_observations(y, noise, **settings)
        return self

    def _base(self):
        """The base's declarations while the correction is off; nothing once it is on."""
        return declared(None if bool(self.active) else self.base)

    def linear_in_parameters(self):
        return self._base().linear_in_parameters()

    def gauss_newton_diagonal(self, y):
        return self._base().gauss_newton_diagonal(y)

    def gauss_newton_max(self, y):
        return self._base().gauss_newton_max(y)

    @property
    def decoder(self):
        return self._base().decoder

    @property
    def decoder_info(self):
        return declared(self.base).decoder_info

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        xb = self.base(y)
        if not bool(self.active):
            return xb
        return xb + self.grid.to_mesh(self.correction(self._inputs(y, xb))).to(xb.dtype)

    def _inputs(self, y: torch.Tensor, xb: torch.Tensor) -> torch.Tensor:
        """The correction's input images: ``Ê b(y)``, and ``Ê x_T(y)`` with a physics filter."""
        g = self.grid.to_grid(xb.to(torch.float32))
        if self.physics is None:
            return g
        with torch.no_grad():
            t = self.physics(y).to(torch.float32)
        return torch.cat([g, self.grid.to_grid(t)], 1)

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        """Also a state dict of the base network alone (a run saved before the correction existed)."""
        if not any(k.startswith(("base.", "correction.", "grid.")) for k in state_dict):
            return self.base.load_state_dict(state_dict, strict, assign)
        return super().load_state_dict(state_dict, strict, assign)

    def _apply(self, fn, recurse=True):
        """``.to(dtype)`` moves the base; the correction stays float32 (a CNN's arithmetic: its output
        corrects a float64 estimate by amounts far above float32 rounding)."""
        super()._apply(fn, recurse)
        self.correction.float()
        self.grid.float()
        return self

    def fit_prior(self, x, y, relative_error, settings: PriorFit = PriorFit(), log=None) -> dict:
        """Fit ``g`` on prior draws ``x`` ``(n, N)``, ``y`` ``(n, m)`` (numpy) with the base frozen;
        ``relative_error(xhat, x)`` is the problem's per-sample relative L²(Ω) error (numpy). Returns
        what was done (``kept``, held-out errors before and after, steps, seconds)."""
        x = np.asarray(x, dtype=float)
        n = len(x)
        gen = torch.Generator().manual_seed(settings.seed)
        perm = torch.randperm(n, generator=gen).numpy()
        n_val = max(1, int(round(settings.held_out * n)))
        val, tr = perm[:n_val], perm[n_val:]
        dtype = next(self.base.parameters()).dtype
        with torch.no_grad():
            parts = [(yb, self.base(yb).float()) for yb in
                     (torch.as_tensor(y[i:i + 512], dtype=dtype) for i in range(0, n, 512))]
            xb = torch.cat([b for _, b in parts])
            inputs = torch.cat([self._inputs(yb, b) for yb, b in parts])
        xt = torch.as_tensor(x, dtype=torch.float32)

        def held_out_error() -> float:
            with torch.no_grad():
                out = xb[val] + self.grid.to_mesh(self.correction(inputs[val]))
            return float(np.mean(relative_error(out.double().numpy(), x[val])))

        before = float(np.mean(relative_error(xb[val].double().numpy(), x[val])))
        best, best_state, bad, step, t0 = before, None, 0, 0, time.perf_counter()
        g = self.correction
        g.requires_grad_(True)
        opt = torch.optim.Adam(g.parameters(), settings.lr)
        try:
            while step < settings.steps and len(tr):
                if settings.time_budget is not None and time.perf_counter() - t0 > settings.time_budget:
                    break
                rows = torch.as_tensor(tr[torch.randint(len(tr), (settings.batch,), generator=gen).numpy()])
                loss = ((xb[rows] + self.grid.to_mesh(g(inputs[rows])) - xt[rows]) ** 2).mean()
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                step += 1
                if step % settings.check_every == 0:
                    err = held_out_error()
                    if log is not None:
                        log(f"prior fit step {step}: held-out x-error {err:.4g} (base {before:.4g})")
                    if math.isfinite(err) and err < best * (1 - settings.min_gain):
                        best, bad = err, 0
                        best_state = {k: v.clone() for k, v in g.state_dict().items()}
                    else:
                        bad += 1
                        if bad >= settings.patience:
                            break
        finally:
            g.requires_grad_(False)
        kept = best_state is not None
        if kept:
            g.load_state_dict(best_state)
        self.active.fill_(kept)
        self.prior_info = {"kept": kept, "draws": n, "held_out": int(n_val), "error_before": before,
                           "error_after": best, "steps": step, "seconds": time.perf_counter() - t0}
        return self.prior_info
