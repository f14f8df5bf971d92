"""Convection by a given velocity field: the matrices that make heat an advection–diffusion problem.

For ``u_t + w·∇u = κΔu`` with a divergence-free ``w`` (``∇·w = 0``) the Galerkin form
adds to ``κK`` the convection matrix

    C_ij = ∫ (w·∇φ_j) φ_i dx                        (not symmetric),

and, where the cell Péclet number ``Pe = |w|h/(2κ)`` exceeds 1 (Galerkin would
oscillate), the streamline diffusion of Brooks & Hughes (1982)

    D_ij = ∫ δ/|w|² (w·∇φ_j)(w·∇φ_i) dx,      δ = max(0, |w|h/2 − κ),

artificial diffusion along the streamlines only, which brings the effective cell
Péclet number down to 1 (upwind-stable) and vanishes once ``h ≤ 2κ/|w|`` (so the
scheme stays consistent: P1 converges at its Galerkin rate on fine meshes).
Both act on the free unknowns of a :class:`~pdeinv.fem.forms.Discretization`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from skfem import BilinearForm


def cellular_flow(amplitude: float = 1.0):
    """``w = a (sin πx cos πy, −cos πx sin πy)``: divergence-free, no flow through the unit
    square's sides, ``w = a (∂ψ/∂y, −∂ψ/∂x)/π`` for the stream function ``ψ = sin πx sin πy``
    (so ``w·∇ψ = 0``: the first Laplace eigenfunction is not advected at all)."""
    def w(x):
        return amplitude * np.stack([np.sin(np.pi * x[0]) * np.cos(np.pi * x[1]),
                                     -np.cos(np.pi * x[0]) * np.sin(np.pi * x[1])])
    return w


def convection(disc, velocity, kappa: float) -> sp.csr_matrix:
    """``C + D`` on the free unknowns (module docstring): convection plus streamline diffusion."""

    @BilinearForm
    def form(u, v, w):
        b = velocity(w.x)
        speed2 = np.maximum(np.sum(b**2, axis=0), 1e-300)
        delta = np.maximum(np.sqrt(speed2) * w.h / 2 - kappa, 0.0)
        bu, bv = np.sum(b * u.grad, axis=0), np.sum(b * v.grad, axis=0)
        return bu * v + delta / speed2 * bu * bv

    A = form.assemble(disc.basis)
    return sp.csr_matrix(A[np.ix_(disc.free, disc.free)])


def max_cell_peclet(disc, velocity, kappa: float) -> float:
    """``max |w| h / (2κ)`` over the mesh's quadrature points."""
    x = disc.basis.mapping.F(disc.basis.X)
    h = disc.basis.mesh.param()
    return float(np.max(np.linalg.norm(velocity(x), axis=0)) * h / (2 * kappa))
