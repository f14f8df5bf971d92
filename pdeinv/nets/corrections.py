"""The nonlinear corrections ``g`` of a refined network ``f(y) = b(y) + g(y, b(y))``
(:mod:`pdeinv.nets.refine`): what ``g`` sees and how it maps that to a correction on the mesh.

Three strategies, chosen by what the mesh is (:func:`pdeinv.nets.defaults.correction_kind`):

* :class:`GridCorrection`: a U-Net (:class:`UNet`) on a regular grid reached through the
  finite-element interpolation (:class:`~pdeinv.fem.grid.GridMap`), ``g = E U(Ê b(y) [, Ê x_T(y)])``:
  parameters independent of the mesh, a local (convolutional) prior, any 2-D/3-D mesh (the SIP
  paper's boxes at 64×64: x-error 0.159 → 0.044, benchmarks/notes/results-history.md).
* :class:`DenseCorrection`: a GELU MLP on the whole observation and estimate,
  ``g = σ_x · MLP([y/σ_y, b(y)/σ_x [, x_T(y)/σ_x]])``: every unknown sees every observation, which a
  nonlinear inverse of a wave or reaction map needs (information travels across the domain), at
  ``O((m + 2N)·h + h² + h·N)`` parameters — for 1-D meshes of at most
  :data:`~pdeinv.nets.defaults.DENSE_MAX_UNKNOWNS` unknowns (sine_gordon_1d: x-error 0.064 where the
  1-D U-Net stops at 0.190).

* :class:`SpanCorrection`: a GELU MLP in the orthonormalized coordinates of the base's decoder, for
  nonlinear physics on meshes too large for the dense MLP (sine_gordon_2d at 16 129 unknowns: x-error
  0.58 → 0.20).

All start at ``g ≡ 0`` (a zero last layer) and run in float32; ``inputs`` is computed once per
fit (the base is frozen), ``forward(inputs)`` is the ``(B, N)`` correction.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F


def _conv(dim: int):
    return {1: nn.Conv1d, 2: nn.Conv2d, 3: nn.Conv3d}[dim]


#: grid points a U-Net applies at once (rows × points per row); a larger batch goes through in chunks of
#: rows, the same numbers per row. Beyond it a batch's activations (48 channels per point) leave the
#: caches: 1 024 rows of heat_boxes' 64² grid took 17 s in one call, 4.6 s in chunks of 64 rows
POINTS = 2**18

#: the channels-last layout of the 2-D and 3-D convolutions: oneDNN's fast path on CPUs (a training step
#: of 32 rows at 64² ~30 % faster than the contiguous layout), and cuDNN's with tensor cores
_LAST = {2: torch.channels_last, 3: torch.channels_last_3d}


#: the widest level's channels as a multiple of the finest's: ``c·min(2^l, WIDEN)`` on level ``l`` (the
#: SIP paper's heat network doubles twice, then holds)
WIDEN = 4

#: the legacy two-level layout's module names (runs saved before the level count was a setting)
_LEGACY = {"e1.": "down.0.", "e2.": "down.1.", "e3.": "down.2.", "u2.": "up.1.", "u1.": "up.0."}


def widths(c: int, levels: int) -> tuple[int, ...]:
    """The channels of each level of :class:`UNet`: ``c·min(2^l, WIDEN)`` for ``l = 0 … levels``."""
    return tuple(c * min(2**level, WIDEN) for level in range(levels + 1))


class UNet(nn.Module):
    """A U-Net ``g`` on ``dim``-dimensional images: ``levels`` halvings of the grid below the full
    resolution, :func:`widths` channels (``c`` at full resolution), two 3×3 convolutions per level on the
    way down, ``up_convs`` per level on the way up (after the upsampled coarser level is concatenated with
    the skip connection), GELU, and a zero-initialized 1×1 output: ``g ≡ 0`` at start. Parameters
    ``≈ 3^dim Σ_l (2 + 1 + up_convs) w_l²``, independent of the mesh. ``UNet(dim, c, ch)`` (two levels,
    one convolution up) is the correction of :class:`GridCorrection`; :func:`pdeinv.nets.unet` takes as
    many levels as its grid allows, up to four (:func:`pdeinv.nets.unet.levels`: a 64² grid's coarsest
    level then sees the whole domain), and two convolutions up."""

    def __init__(self, dim: int, c: int = 16, channels_in: int = 1, levels: int = 2, up_convs: int = 1):
        super().__init__()
        Conv, act = _conv(dim), nn.GELU
        w = widths(c, levels)

        def convs(a, b, n, stride=1):
            layers = [Conv(a, b, 3, padding=1, stride=stride), act()]
            for _ in range(n - 1):
                layers += [Conv(b, b, 3, padding=1), act()]
            return nn.Sequential(*layers)

        self.dim, self.levels, self.up_convs = dim, levels, up_convs
        self.down = nn.ModuleList([convs(channels_in, w[0], 2)]
                                  + [convs(w[i], w[i + 1], 2, stride=2) for i in range(levels)])
        self.up = nn.ModuleList([convs(w[i + 1] + w[i], w[i], up_convs) for i in range(levels)])
        self.out = Conv(w[0], 1, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        if dim in _LAST:
            self.to(memory_format=_LAST[dim])
        self._register_load_state_dict_pre_hook(_legacy_names)

    def forward(self, g: torch.Tensor) -> torch.Tensor:
        rows = max(1, POINTS // max(1, int(np.prod(g.shape[2:]))))  # chunks of rows (:data:`POINTS`)
        if g.shape[0] > rows:
            return torch.cat([self._levels(part) for part in torch.split(g, rows)])
        return self._levels(g)

    def _levels(self, g: torch.Tensor) -> torch.Tensor:
        mode = {1: "linear", 2: "bilinear", 3: "trilinear"}[self.dim]
        skips = []
        for block in self.down:
            g = block(g)
            skips.append(g)
        h = skips.pop()
        for level in reversed(range(self.levels)):
            s = skips.pop()
            h = F.interpolate(h, size=s.shape[2:], mode=mode, align_corners=False)
            h = self.up[level](torch.cat([h, s], 1))
        return self.out(h)


def _legacy_names(state, prefix, *_):
    """Renames a legacy two-level state dict's keys (``e1 … u1``) to this layout's, in place."""
    for key in [k for k in state if k.startswith(prefix)]:
        rest = key[len(prefix):]
        for old, new in _LEGACY.items():
            if rest.startswith(old):
                state[prefix + new + rest[len(old):]] = state.pop(key)
                break


class SpectralFilter(nn.Module):
    """A fixed linear estimate from the physics alone, ``x_T = synth (g/(g² + α) ⊙ projᵀ y)`` in an
    operator's spectral basis (the modal heat backend): Tikhonov with ``α = rel·max g²``, nothing learned,
    full rank. Its buffers are not saved (rebuilt from the problem, deterministic)."""

    def __init__(self, modes, rel_alpha: float):
        super().__init__()
        g = np.asarray(modes.g, dtype=float)
        alpha = rel_alpha * float(np.max(g**2)) if g.size else 0.0
        self.register_buffer("proj", torch.as_tensor(np.asarray(modes.proj, dtype=float)), persistent=False)
        den = g**2 + alpha  # 0 only where every gain is 0 (a κT that leaves nothing): a zero filter
        filt = np.divide(g, den, out=np.zeros_like(g), where=den > 0)
        self.register_buffer("filt", torch.as_tensor(filt), persistent=False)
        self.register_buffer("synth", torch.as_tensor(np.asarray(modes.synth, dtype=float)), persistent=False)

    def _apply(self, fn, recurse=True):
        """Moves with its network (a device) but stays float64 (``.float()`` included): its filter may
        amplify by ``1/√α`` up to 1e4 at rounding-level α, far above float32 rounding."""
        for k, v in self._buffers.items():  # a leaf module: buffers only
            moved = fn(v)
            self._buffers[k] = v.to(moved.device) if moved.dtype != v.dtype else moved
        return self

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        y = y.to(self.proj.dtype)
        return ((y @ self.proj) * self.filt) @ self.synth.T


def _physics(physics, y, t=None) -> torch.Tensor:
    """``x_T(y)`` in float32: ``t`` if given, else the filter's product (no gradient)."""
    if t is None:
        with torch.no_grad():
            t = physics(y)
    return t.to(torch.float32)


#: grid points × draws × ``3^dim`` of one prior-fit step of the U-Net correction
#: (:attr:`GridCorrection.fit_batch`): the CPU convolutions unfold ``3^dim × channels`` floats per point and
#: draw for the backward; heat_3d at 29 791 unknowns with 32 draws per step held 4–5 GB per step (peak RSS
#: 13.5 GB), 10 draws under this bound. 2-D 65 025 unknowns: 14 draws; 2-D 4k and 3-D 3k keep 32
FIT_BATCH_POINTS = 2**23


def fit_batch(kind: str, points: int, dim: int) -> int:
    """Draws per prior-fit step of a correction of ``kind`` on ``points`` grid points in ``dim``
    dimensions, without building it: :attr:`GridCorrection.fit_batch` (with as many grid points as
    unknowns), else 128."""
    if kind != "grid":
        return DenseCorrection.fit_batch
    return int(min(32, max(2, FIT_BATCH_POINTS // (max(points, 1) * 3**dim))))


def unet_macs(points: int, dim: int, c: int = 16, channels_in: int = 2, levels: int = 2,
              up_convs: int = 1) -> int:
    """Multiply-adds of one forward pass of :class:`UNet` on one image of ``points`` pixels: each
    convolution's weights times the pixels of its level (``points·2^(−dim·l)`` on level ``l``)."""
    k, w = 3**dim, widths(c, levels)
    total = points * (channels_in * w[0] * k + w[0] * w[0] * k + w[0])  # level 0 down, and the output
    for level in range(1, levels + 1):
        below = points / 2 ** (dim * level)
        total += below * (w[level - 1] * w[level] + w[level] ** 2) * k  # down: strided, then one more
    for level in range(levels):
        here = points / 2 ** (dim * level)
        total += here * ((w[level + 1] + w[level]) * w[level] + (up_convs - 1) * w[level] ** 2) * k
    return int(total)


def mlp_macs(widths) -> int:
    """Multiply-adds of one forward pass of a dense MLP with layer ``widths`` on one sample."""
    return int(sum(a * b for a, b in zip(widths[:-1], widths[1:], strict=True)))


def correction_macs(kind: str, N: int, m: int, dim: int, physics: bool, hidden=(512, 512, 512),
                    decoder: int | None = None) -> int:
    """Multiply-adds of one forward pass of a correction of ``kind`` on one sample, from the problem's
    sizes alone (the plan and the prior stage count with it): the U-Net on ``N`` grid points, the dense
    MLP on ``(y, b [, x_T])``, or the MLP in a ``decoder``-column span and its synthesis."""
    if kind == "grid":
        return unet_macs(N, dim, channels_in=2 if physics else 1)
    if kind == "span":
        k = decoder or min(N, 512)
        return mlp_macs((k, *hidden, k)) + 2 * k * N
    return mlp_macs((N * (2 if physics else 1) + m, *hidden, N))


class GridCorrection(nn.Module):
    """``g = E U(Ê b(y) [, Ê x_T(y)])`` (module docstring): ``grid`` a
    :class:`~pdeinv.fem.grid.GridMap`, ``physics`` an optional :class:`SpectralFilter` (a second channel)."""

    #: draws per step of the prior fit: 32, fewer where one step's unfolded convolutions would pass
    #: :data:`FIT_BATCH_POINTS`
    @property
    def fit_batch(self) -> int:
        shape = self.grid.shape
        return int(min(32, max(2, FIT_BATCH_POINTS // (int(np.prod(shape)) * 3 ** len(shape)))))

    #: Adam's lr of the prior fit (``PriorFit(lr=None)``): on heat_boxes at 64², 505 steps at 4e-3 reach a
    #: held-out 0.036 where 1e-3 reaches 0.048, and 1 011 steps at 1e-3 0.040 (the fit is far from its
    #: plateau at the counted steps, so larger steps win; the plateau rule's restarts quarter it)
    fit_lr = 4e-3

    def __init__(self, grid, channels: int = 16, dim: int | None = None,
                 physics: SpectralFilter | None = None):
        super().__init__()
        self.grid, self.physics = grid, physics
        self.unet = UNet(dim or len(grid.shape), channels, 1 if physics is None else 2)

    def prepare(self, y: torch.Tensor, xb: torch.Tensor) -> None:
        """Nothing to fit before the fit (the grid maps are fixed)."""

    def inputs(self, y: torch.Tensor, xb: torch.Tensor, t: torch.Tensor | None = None) -> torch.Tensor:
        """``Ê b(y)``, and ``Ê x_T(y)`` with a physics filter (``t``: ``x_T(y)`` if already computed):
        ``(B, channels, *grid)``."""
        g = self.grid.to_grid(xb.to(torch.float32))
        if self.physics is None:
            return g
        t = _physics(self.physics, y, t)
        return torch.cat([g, self.grid.to_grid(t)], 1)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        return self.grid.to_mesh(self.unet(inputs))

    def example_inputs(self, batch: int) -> torch.Tensor:
        """Random inputs of :meth:`inputs`' shape ``(batch, channels, *grid)``: a step's cost, no draw."""
        return torch.randn(batch, 1 if self.physics is None else 2, *self.grid.shape)


class DenseCorrection(nn.Module):
    """``g = σ_x · MLP([y/σ_y, b/σ_x [, x_T/σ_x]])`` (module docstring): ``hidden`` GELU layers, zero last
    layer; ``σ_y``, ``σ_x`` the root-mean-square of the fit's observations and base estimates
    (:meth:`prepare`), kept in the state dict."""

    fit_batch = 128
    fit_lr = 1e-3  # Adam's lr of the prior fit (PriorFit(lr=None))

    def __init__(self, n_out: int, n_in: int, hidden=(512, 512, 512), physics: SpectralFilter | None = None):
        super().__init__()
        self.physics = physics
        widths = [n_in + n_out * (1 if physics is None else 2), *hidden]
        layers = []
        for a, b in zip(widths[:-1], widths[1:], strict=True):
            layers += [nn.Linear(a, b), nn.GELU()]
        self.mlp = nn.Sequential(*layers, nn.Linear(widths[-1], n_out))
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)
        self.register_buffer("y_scale", torch.ones(()))
        self.register_buffer("x_scale", torch.ones(()))

    def prepare(self, y: torch.Tensor, xb: torch.Tensor) -> None:
        """``σ_y``, ``σ_x``: root-mean-square of ``y`` and of the base's estimates ``xb`` (1 where zero)."""
        for buf, v in ((self.y_scale, y), (self.x_scale, xb)):
            rms = float(torch.sqrt(torch.mean(v.double() ** 2)))
            buf.fill_(rms if rms > 0 and np.isfinite(rms) else 1.0)

    def inputs(self, y: torch.Tensor, xb: torch.Tensor, t: torch.Tensor | None = None) -> torch.Tensor:
        """``[y/σ_y, b/σ_x [, x_T/σ_x]]`` (``t``: ``x_T(y)`` if already computed)."""
        parts = [y.to(torch.float32) / self.y_scale, xb.to(torch.float32) / self.x_scale]
        if self.physics is not None:
            parts.append(_physics(self.physics, y, t) / self.x_scale)
        return torch.cat(parts, 1)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        return self.x_scale * self.mlp(inputs)

    def example_inputs(self, batch: int) -> torch.Tensor:
        """Random inputs of :meth:`inputs`' shape ``(batch, width)``: what a step costs, before any draw."""
        return torch.randn(batch, self.mlp[0].in_features)


class SpanCorrection(nn.Module):
    """``g = σ · MLP(b Qᵀ / σ) Q`` in the base's decoder span: ``Q = L⁻¹ D`` the decoder's rows
    orthonormalized (``D Dᵀ = L Lᵀ``, so ``‖u Q‖ = ‖u‖`` and the fit's Euclidean loss is the field's),
    ``b Qᵀ`` the base's estimate in those coordinates (its exact coordinates: ``b = c D``), ``σ`` their
    root-mean-square. Every output coefficient sees every input one (a nonlinear wave's inverse mixes the
    domain) at ``O(k·h + h² + k·N)`` numbers for ``k`` decoder columns: sine_gordon_2d at 16 129 unknowns
    (``k`` = 279) takes a reduced SIP base from 0.58 to 0.20 on held-out draws (3 072 draws, 52 s; the
    same MLP on a Euclidean loss in ``c`` diverged, 0.8–1.8), where the dense MLP on the mesh would have
    2.5·10⁷ weights and the U-Net gained 0.01 in 546 s."""

    fit_batch = 128
    fit_lr = 1e-3  # Adam's lr of the prior fit (PriorFit(lr=None))
    physics = None

    def __init__(self, decoder: torch.Tensor, hidden=(512, 512, 512)):
        super().__init__()
        D = torch.as_tensor(decoder, dtype=torch.float64)
        L = torch.linalg.cholesky(D @ D.T)
        self.register_buffer("Q", torch.linalg.solve_triangular(L, D, upper=False).float())
        widths = [D.shape[0], *hidden]
        layers = []
        for a, b in zip(widths[:-1], widths[1:], strict=True):
            layers += [nn.Linear(a, b), nn.GELU()]
        self.mlp = nn.Sequential(*layers, nn.Linear(widths[-1], D.shape[0]))
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)
        self.register_buffer("scale", torch.ones(()))

    def prepare(self, y: torch.Tensor, xb: torch.Tensor) -> None:
        """``σ``: the root-mean-square of the base's coordinates ``b Qᵀ`` (1 where zero)."""
        rms = float(torch.sqrt(torch.mean((xb.to(torch.float32) @ self.Q.T).double() ** 2)))
        self.scale.fill_(rms if rms > 0 and np.isfinite(rms) else 1.0)

    def inputs(self, y: torch.Tensor, xb: torch.Tensor, t: torch.Tensor | None = None) -> torch.Tensor:
        """``b Qᵀ / σ``: ``(B, k)``."""
        return (xb.to(torch.float32) @ self.Q.T) / self.scale

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        return (self.scale * self.mlp(inputs)) @ self.Q

    def example_inputs(self, batch: int) -> torch.Tensor:
        """Random inputs of :meth:`inputs`' shape ``(batch, k)``."""
        return torch.randn(batch, self.Q.shape[0])
