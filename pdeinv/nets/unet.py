"""A U-Net the update rules train end to end, on any mesh of dimension 1–3 (``--net unet``).

The SIP paper's network (Holl, Koltun & Thuerey 2022, heat experiment) on finite elements, reached
through the finite-element interpolation (:class:`~pdeinv.fem.grid.GridMap`: ``Ê`` nodes → grid,
``E`` grid → nodes)::

    f(y) = s_x · E U( Ê [y / s_y,  x_T(y) / s_x] )  [+ x_T(y)]

* ``U`` is :class:`~pdeinv.nets.corrections.UNet` (GELU, skip connections, zero last layer): parameters
  independent of the mesh, a local, translation-equivariant prior. It halves the grid down to a coarsest
  level of at least :data:`COARSEST` points per axis, at most :data:`LEVELS` times (:func:`levels`), so
  that level's 3×3 convolutions see the whole domain: a 64² grid gets the SIP paper's four levels.
* Its input channels are what the physics gives without training: the observation itself where it lives
  on the unknowns (``m = N``: a final state), and the physics' own linear estimate ``x_T(y)`` where the
  operator has a spectral basis (Tikhonov at the noise level, :class:`~pdeinv.nets.corrections.
  SpectralFilter`; not saved, rebuilt from the problem). At least one of the two must exist.
* ``residual=True`` adds ``x_T(y)`` to the output (the FBPConvNet pattern): the network starts at the
  physics' linear estimate and learns only what it changes. ``False`` (the paper's form) starts at 0.
* ``s_y``, ``s_x`` are the root-mean-square of the training observations and of ``x_T`` (or ``s_y``)
  on them (:meth:`fit_observations`, never ``x``), so the convolutions see O(1) inputs; saved.

The network is not linear in its parameters: SIP fits its proxy with Adam on minibatches (the paper's
optimizer, :data:`pdeinv.methods.presets.SIP_MLP`), HIG takes its matrix-free route
(:mod:`pdeinv.methods.hig.randomized`), and GD / Adam the plain gradient. Parameters
``≈ 3^dim Σ_l 5 w_l²`` over the levels' widths ``w_l = c·min(2^l, 4)`` (16 channels, four levels in 2-D,
two inputs: 487 281), buffers ``O(N·2^dim)``; initialisation is
seeded by ``torch.manual_seed`` like every pdeinv network.
"""

from __future__ import annotations

import numpy as np
import torch

from .._checks import count, flag, shown
from .._checks import problem as _problem
from .corrections import SpectralFilter, UNet
from .protocol import Network

#: channels of the U-Net at full resolution (``2c``, then ``4c`` on the coarser levels): the SIP paper's width
CHANNELS = 16

#: the most halvings of the grid: the SIP paper's heat network's four levels
LEVELS = 4

#: the fewest grid points per axis on the coarsest level: a 3×3 convolution on fewer is mostly padding
COARSEST = 4

#: 3×3 convolutions per level on the way up (after the skip connection): the paper's two
UP_CONVS = 2


def levels(shape) -> int:
    """Halvings of a grid of ``shape`` (:data:`LEVELS` at most) that keep :data:`COARSEST` points per
    axis on the coarsest level; stride-2 convolutions round up (65 → 33 → 17 → 9 → 5: four levels)."""
    side, count_ = min(int(s) for s in shape), 0
    while count_ < LEVELS and (side + 1) // 2 >= COARSEST:
        side, count_ = (side + 1) // 2, count_ + 1
    return count_


def _rms(v: torch.Tensor) -> float:
    r = float(torch.sqrt(torch.mean(v.double() ** 2)))
    return r if r > 0 and np.isfinite(r) else 1.0


class MeshUNet(Network):
    """``f(y)`` of the module docstring. ``grid``: a :class:`~pdeinv.fem.grid.GridMap` of the unknowns;
    ``physics``: a :class:`SpectralFilter` or ``None``; ``observed``: whether ``y`` lives on the unknowns
    (``m = N``) and enters as a channel; ``depth``: the U-Net's levels (``None``: :func:`levels` of the
    grid), ``up_convs``: its convolutions per level on the way up."""

    def __init__(self, grid, physics: SpectralFilter | None, observed: bool, channels: int = CHANNELS,
                 residual: bool = False, depth: int | None = None, up_convs: int = UP_CONVS):
        super().__init__()
        from ..fem.grid import GridMap

        if not isinstance(grid, GridMap):
            raise TypeError(f"grid={shown(grid)} is {type(grid).__name__}; expected a "
                            "pdeinv.fem.grid.GridMap of the unknowns, GridMap(problem.points, spacing(mesh))")
        if physics is not None and not isinstance(physics, torch.nn.Module):
            raise TypeError(f"physics={shown(physics)} is {type(physics).__name__}; expected a "
                            "pdeinv.nets.corrections.SpectralFilter (a torch.nn.Module y -> x) or None")
        flag(observed, "observed")
        channels = count(channels, "channels")
        flag(residual, "residual")
        depth = levels(grid.shape) if depth is None else count(depth, "depth", minimum=0)
        up_convs = count(up_convs, "up_convs")
        if physics is None and not observed:
            raise ValueError("MeshUNet needs an input: observations on the unknowns (m = N) or a physics "
                             "estimate (physics=SpectralFilter)")
        if residual and physics is None:
            raise ValueError("MeshUNet(residual=True) needs the physics estimate it adds to (physics=…)")
        self.grid, self.physics, self.observed, self.residual = grid, physics, bool(observed), bool(residual)
        inputs = int(self.observed) + int(physics is not None)
        self.unet = UNet(len(grid.shape), channels, inputs, depth, up_convs)
        self.register_buffer("y_scale", torch.ones((), dtype=torch.float64))
        self.register_buffer("x_scale", torch.ones((), dtype=torch.float64))

    def fit_observations(self, y, noise=None, **settings) -> MeshUNet:
        """``s_y`` and ``s_x`` from the training observations ``y`` (module docstring)."""
        y = torch.as_tensor(y)
        with torch.no_grad():
            self.y_scale.fill_(_rms(y))
            self.x_scale.fill_(_rms(self.physics(y)) if self.physics is not None else _rms(y))
        return self

    def _apply(self, fn, recurse=True):
        """``.float()`` / ``.double()`` move the U-Net; the physics filter and the scales stay float64."""
        super()._apply(fn, recurse)
        for k in ("y_scale", "x_scale"):
            self._buffers[k] = self._buffers[k].to(torch.float64)
        return self

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        """``(B, m) -> (B, N)``; one sample ``(m,) -> (N,)`` (``torch.func``'s per-sample routes pass it)."""
        if y.dim() == 1:
            return self.forward(y[None])[0]
        dtype = next(self.unet.parameters()).dtype
        channels = []
        if self.observed:
            channels.append(self.grid.to_grid((y / self.y_scale.to(y.dtype)).to(dtype)))
        t = None
        if self.physics is not None:
            t = self.physics(y)
            channels.append(self.grid.to_grid((t / self.x_scale).to(dtype)))
        out = self.grid.to_mesh(self.unet(torch.cat(channels, 1))) * self.x_scale.to(dtype)
        return out if not self.residual else t.to(dtype) + out


def inputs(problem) -> int:
    """The U-Net's input channels for ``problem`` (module docstring): the observations where ``m = N``,
    the physics estimate where the operator has a spectral basis."""
    from ..physics.capabilities import modal_basis

    _problem(problem)
    return int(problem.operator.n_out == problem.N) + int(modal_basis(problem.operator) is not None)


def size(problem, channels: int = CHANNELS, depth: int | None = None, up_convs: int = UP_CONVS) -> dict:
    """What :func:`unet`'s network holds for ``problem``, without its grid: ``params`` (the U-Net's, the
    same on every mesh of a dimension and depth; ``depth=None``: :func:`levels` of the problem's grid),
    ``buffers`` (the grid maps' ``2^dim`` indices and weights per unknown, an upper bound of ``4N`` grid
    points, two scales) and ``widest`` (one sample's largest activation: ``2c`` channels up plus ``c`` of
    the skip on at most ``4N`` grid points)."""
    from ..fem.grid import grid_shape, spacing

    _problem(problem)
    channels = count(channels, "channels")
    dim = problem.points.shape[0]
    if depth is None:
        mesh = None if problem.disc is None else problem.disc.basis.mesh
        depth = LEVELS if mesh is None else levels(grid_shape(problem.points, spacing(mesh))[0])
    depth = count(depth, "depth", minimum=0)
    params = sum(q.numel() for q in UNet(dim, channels, max(inputs(problem), 1), depth,
                                          count(up_convs, "up_convs")).parameters())
    return {"params": params, "buffers": 2 * problem.N * 2**dim + 4 * problem.N + 2,
            "widest": 3 * channels * 4 * problem.N}


def unet(channels: int = CHANNELS, residual: bool | None = None, refine: bool = True,
         depth: int | None = None, up_convs: int = UP_CONVS):
    """``problem -> network``: a :class:`MeshUNet` (in :func:`~pdeinv.nets.defaults.refined`'s wrapper with
    ``refine``) for a problem whose unknowns are nodal values on a mesh of dimension 1–3:
    the physics estimate where the operator has a spectral basis, the observations where ``m = N``.
    ``residual`` (``None``: no, the paper's form) adds the physics estimate to the output. Noise-free, that
    estimate already reproduces ``y`` to rounding: a residual network then starts at a rounding-level loss
    and the rule has nothing left to fit; from zero the rule trains the whole map. ``refine`` wraps it as
    the default network's base (:func:`pdeinv.nets.defaults.refined`): a correction and a data-consistency
    layer, off and untrained, for the prior stage to fit on top of what the rule trained (``prior=None`` /
    ``--prior-fit 0``: the U-Net alone). ``depth`` (``None``: :func:`levels` of the problem's grid) and
    ``up_convs`` shape the U-Net (:class:`~pdeinv.nets.corrections.UNet`); a saved run records both."""
    channels = count(channels, "channels")
    depth = None if depth is None else count(depth, "depth", minimum=0)
    up_convs = count(up_convs, "up_convs")
    if residual is not None:
        flag(residual, "residual")
    flag(refine, "refine")

    def build(problem) -> torch.nn.Module:
        from ..fem.grid import GridMap, spacing
        from ..inverse import NOISE_FREE_REL_ALPHA
        from ..physics.capabilities import modal_basis

        _problem(problem)
        mesh = None if problem.disc is None else problem.disc.basis.mesh
        if mesh is None or not 1 <= problem.points.shape[0] <= 3:
            raise ValueError(f"net 'unet' needs unknowns at the nodes of a 1-3-D mesh; problem "
                             f"{problem.name!r} has none")
        modes = modal_basis(problem.operator)
        noise = float(problem.noise or 0.0)
        physics = None if modes is None else SpectralFilter(modes, max(noise, NOISE_FREE_REL_ALPHA**0.5) ** 2)
        observed = bool(problem.operator.n_out == problem.N)
        if physics is None and not observed:
            raise ValueError(f"net 'unet' on problem {problem.name!r}: its observations are not on the "
                             "unknowns and its operator has no spectral basis for a physics estimate; use "
                             "--net default")
        res = False if residual is None else residual
        grid = GridMap(problem.points, spacing(mesh))
        net = MeshUNet(grid, physics, observed, channels, res, depth, up_convs)
        if not refine:
            return net
        from .defaults import refined

        return refined(problem, net)
    return build
