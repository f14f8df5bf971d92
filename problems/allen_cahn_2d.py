"""Allen–Cahn heat on the unit square, u = 0 on the boundary: recover u(0) from u(T).

As allen_cahn_1d on 16×16×2 P1 triangles (225 unknowns) with 50 backward-Euler steps, each solved
by the chord iteration with one frozen, once-factorized matrix for the whole batch (block-LU Newton
only for columns where it does not contract: :class:`pdeinv.physics.reaction.ReactionHeat`);
``--set n=32`` for 961 unknowns, ``n=128`` for 16 129. ``strength`` (default 1) is r in
``f(u) = r (u³ − u)``; ``mesh=path`` reads a triangle mesh instead.
"""

from pdeinv import mesh, nonlinear_scenes
from pdeinv import settings as s

SETTINGS = {**nonlinear_scenes.ALLEN_CAHN, "n": (16, s.positive_int), "steps": (50, s.positive_int),
            "mesh": (None, s.optional_path)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "allen_cahn_2d")
    m = mesh.load(cfg["mesh"], dim=2) if cfg["mesh"] else mesh.unit_square(cfg["n"])
    return nonlinear_scenes.allen_cahn("allen_cahn_2d", m, cfg)
