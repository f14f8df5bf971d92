"""Heat on the unit square (or a mesh file), u = 0 on the boundary: recover u(0) from u(T).

Defaults (κT = 0.01, 32×32×2 P1 triangles, 961 unknowns, 100 backward-Euler
steps): modes sin(jπx)sin(kπy) decay like e^{-κTπ²(j²+k²)}; about 55 of 961 keep
an amplification ≥ 1e-3. ``mesh=path`` reads a triangle mesh with meshio instead
(``n`` is then ignored).
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s

SETTINGS = {**scenes.HEAT, "n": (32, s.positive_int), "mesh": (None, s.optional_path)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "heat_2d")
    m = mesh.load(cfg["mesh"], dim=2) if cfg["mesh"] else mesh.unit_square(cfg["n"])
    return scenes.heat("heat_2d", m, cfg)
