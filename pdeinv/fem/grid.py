"""A regular grid over a mesh's bounding box, and the two maps between nodal fields and grid images.

Convolutional networks need a tensor grid; finite-element fields live on the free unknowns of a
mesh. :class:`GridMap` builds the grid ``lo + h·i`` (``i`` a multi-index, spacing ``h`` the mesh's
median element extent, so a structured mesh's nodes *are* grid points) and

* ``to_mesh`` (``E``, grid → unknowns): multilinear interpolation at the unknowns' coordinates,
  ``x_j = Σ_c w_jc g[i_jc]`` over the ``2^dim`` corners of the grid cell holding node ``j``
  (exact for multilinear fields; the identity on nodes that are grid points);
* ``to_grid`` (``Ê = D⁻¹Eᵀ``, unknowns → grid): its transpose normalized per grid point,
  ``g_i = Σ_j E_ji x_j / Σ_j E_ji`` (zero where no unknown is near: outside the domain, on a
  Dirichlet boundary). ``E Ê x = x`` when every unknown is a grid point.

Both are gathers/scatters of fixed indices and weights (buffers): O(N·2^dim) work, differentiable in
torch, any dimension 1–3, any mesh.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch
from torch import nn


def spacing(mesh) -> float:
    """The median over element edges of their largest coordinate extent: a structured mesh's step."""
    t, p = mesh.t, mesh.p
    ext = [np.abs(p[:, t[a]] - p[:, t[b]]).max(0) for a, b in itertools.combinations(range(t.shape[0]), 2)]
    ext = np.concatenate(ext)
    return float(np.median(ext[ext > 0]))


def grid_shape(points: np.ndarray, h: float, max_points: int = 2**21) -> tuple[np.ndarray, np.ndarray]:
    """``(shape, spacing)`` of :class:`GridMap`'s grid for unknowns at ``points``: spacing about ``h``,
    grown to keep at most ``max_points`` grid points, and at least 2 points per axis."""
    dim = points.shape[0]
    span = points.max(1) - points.min(1)
    h = max(h, float(np.prod(np.maximum(span, h)) / max_points) ** (1 / dim))
    shape = np.maximum(np.round(span / h).astype(int) + 1, 2)
    return shape, np.where(span > 0, span / np.maximum(shape - 1, 1), 1.0)


class GridMap(nn.Module):
    """``E`` and ``Ê`` (module docstring) for unknowns at ``points`` (``(dim, N)``) on a grid of
    spacing about ``h`` (at most ``max_points`` grid points: the spacing grows to fit)."""

    def __init__(self, points: np.ndarray, h: float, max_points: int = 2**21):
        super().__init__()
        dim, lo = points.shape[0], points.min(1)
        shape, step = grid_shape(points, h, max_points)
        u = (points - lo[:, None]) / step[:, None]  # grid coordinates of the unknowns
        cell = np.clip(np.floor(u + 1e-9).astype(int), 0, shape[:, None] - 2)
        frac = np.clip(u - cell, 0.0, 1.0)
        idx, w = [], []
        for corner in itertools.product((0, 1), repeat=dim):
            c = np.array(corner)[:, None]
            idx.append(np.ravel_multi_index(tuple(cell + c), tuple(shape)))
            w.append(np.prod(np.where(c == 1, frac, 1 - frac), axis=0))
        idx, w = np.stack(idx, 1), np.stack(w, 1)  # (N, 2^dim)
        norm = np.bincount(idx.ravel(), w.ravel(), minlength=int(np.prod(shape)))
        self.shape = tuple(int(s) for s in shape)
        self.register_buffer("index", torch.as_tensor(idx))
        self.register_buffer("weight", torch.as_tensor(w))
        inv = np.where(norm > 1e-12, 1 / np.maximum(norm, 1e-12), 0.0)
        self.register_buffer("inv_norm", torch.as_tensor(inv))

    def to_grid(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, N)`` nodal fields → ``(B, 1, *shape)`` grid images (``Ê``)."""
        w = self.weight.to(x.dtype)
        g = x.new_zeros(x.shape[0], self.inv_norm.numel())
        g.index_add_(1, self.index.reshape(-1), (x[:, :, None] * w).reshape(x.shape[0], -1))
        return (g * self.inv_norm.to(x.dtype)).reshape(x.shape[0], 1, *self.shape)

    def to_mesh(self, g: torch.Tensor) -> torch.Tensor:
        """``(B, 1, *shape)`` grid images → ``(B, N)`` nodal fields (``E``)."""
        flat = g.reshape(g.shape[0], -1)
        return (flat[:, self.index] * self.weight.to(g.dtype)).sum(-1)
