"""Heat on (0, 1), u = 0 at both ends: recover u(0) from u(T).

Defaults (κT = 0.01, 64 P1 elements, 100 backward-Euler steps): of the 63
modes sin(kπx), only k ≤ 8 keep an amplification e^{-κTπ²k²} ≥ 1e-3, so the
inverse problem is clearly ill-conditioned yet solvable for the smooth part.
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s

SETTINGS = {**scenes.HEAT, "n": (64, s.positive_int)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "heat_1d")
    return scenes.heat("heat_1d", mesh.interval(cfg["n"]), cfg)
