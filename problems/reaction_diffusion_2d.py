"""Reaction–diffusion on the unit square, u = 0 on the boundary: recover u(0) from u(T).

``M u' + (κK + rM) u = 0``: heat with a linear decay of rate ``r`` (a substance that diffuses and
is consumed), written the cheap way, ``C = rM`` added to ``κK``. Every matrix stays symmetric, so
``backend='auto'`` offers the modal form over ``(κK + rM) φ = μ M φ``, ``μ = κλ + r``: each mode
``sin(jπx)sin(kπy)`` decays like ``e^{-(κπ²(j²+k²) + r)T}``. The reaction damps every mode by the
same ``e^{-rT}``, so it scales the data down without changing which modes the data can resolve.

Defaults: κ = 0.01, r = 1, T = 1, 32×32×2 P1 triangles (961 unknowns), 100 backward-Euler steps.
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s

SETTINGS = {**scenes.HEAT, "n": (32, s.positive_int), "reaction": (1.0, s.nonnegative)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "reaction_diffusion_2d")
    return scenes.heat("reaction_diffusion_2d", mesh.unit_square(cfg["n"]), cfg)
