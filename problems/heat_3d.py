"""Heat in the unit cube (or a tetra mesh file), u = 0 on the boundary: recover u(0) from u(T).

Defaults (κT = 0.01, 10×10×10 cubes of 6 P1 tetrahedra, 729 unknowns, 100 backward-Euler
steps, the settings of heat_2d): modes sin(jπx)sin(kπy)sin(lπz) decay like
e^{-κTπ²(j²+k²+l²)}; MODES_SURVIVE of 729 keep an amplification ≥ 1e-3 (counted on the
discrete eigenvalues). ``backend='auto'`` picks the modal operator (Weyl's 3-D count).
``mesh=path`` reads a tetra mesh with meshio instead (``n`` is then ignored).
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s

SETTINGS = {**scenes.HEAT, "n": (10, s.positive_int), "mesh": (None, s.optional_path)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "heat_3d")
    m = mesh.load(cfg["mesh"]) if cfg["mesh"] else mesh.unit_cube(cfg["n"])
    return scenes.heat("heat_3d", m, cfg)
