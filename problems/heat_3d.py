"""Heat in the unit cube (or a tetra mesh file), u = 0 on the boundary: recover u(0) from u(T).

Defaults (κT = 0.01, 10×10×10 cubes of 6 P1 tetrahedra, 729 unknowns, 100 backward-Euler
steps, the settings of heat_2d): modes sin(jπx)sin(kπy)sin(lπz) decay like
e^{-κTπ²(j²+k²+l²)}: 232 of them keep an amplification ≥ 1e-3, but this coarse mesh
resolves only the lowest (its eigenvalues lie above the continuous ones): 119 of the 729
discrete modes keep ≥ 1e-3, 67 keep ≥ 1e-2. ``backend='auto'`` picks the modal operator
(Weyl's 3-D count exceeds N, so all modes by one dense eigendecomposition; 694 kept above
the 1e-14 tolerance). Default CLI run (``pdeinv train heat_3d``: Adam, 1000 steps, one
thread): x-error 0.26, 18 s of training, 30 s in all.
P2 has 8× the unknowns at the same ``n`` (6859 at n=10): use ``n=5`` for 729.
``mesh=path`` reads a tetra mesh with meshio instead (``n`` is then ignored).
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s

SETTINGS = {**scenes.HEAT, "n": (10, s.positive_int), "mesh": (None, s.optional_path)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "heat_3d")
    m = mesh.load(cfg["mesh"], dim=3) if cfg["mesh"] else mesh.unit_cube(cfg["n"])
    return scenes.heat("heat_3d", m, cfg)
