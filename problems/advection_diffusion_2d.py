"""Advection–diffusion on the unit square: recover u(0) from u(T), ``M u' + (κK + C) u = 0``.

A dye released in the cellular flow ``w = a (sin πx cos πy, −cos πx sin πy)``
(divergence-free, no flow through the walls; :func:`pdeinv.fem.advection.cellular_flow`)
is carried around four vortices while it diffuses; u = 0 on the boundary. The
operator is *not symmetric* (convection), so it exercises what the symmetric scenes
cannot: transposed solves in the adjoint and no modal basis (``backend='auto'`` picks time
stepping, a dense matrix or a truncated SVD by the cost of a run, :mod:`pdeinv.physics.backends.compiled`;
with the SVD the local inverse is a filter per singular value).

Defaults: κ = 0.01, a = 0.4, 32×32×2 P1 triangles (961 unknowns), T = 1 (a particle
travels about 0.4, a third of the way round its vortex), 50 backward-Euler steps. The
cell Péclet number ``|w|h/(2κ)`` is at most 0.88 there, so the Galerkin scheme is
stable as it is; at higher speeds streamline diffusion switches on where it exceeds 1
(:mod:`pdeinv.fem.advection`).
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s

SETTINGS = {**scenes.HEAT, **scenes.COMPILED,
            "T": (1.0, s.positive), "steps": (50, s.positive_int),
            "n": (32, s.positive_int), "speed": (0.4, s.nonnegative)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "advection_diffusion_2d")
    return scenes.advection_diffusion("advection_diffusion_2d", mesh.unit_square(cfg["n"]), cfg)
