"""Wave in the unit cube (or a tetra mesh file), u = 0 on the boundary, v(0) = 0: recover u(0) from u(T).

Defaults: c = 1, T = 0.5, 50 Newmark steps (the settings of wave_2d), 10×10×10 cubes of
6 P1 tetrahedra (729 unknowns); ``backend='auto'`` compiles the run to a dense matrix.
Default CLI run (Adam, 1000 steps, one thread): x-error 0.27, 15 s of training, 30 s in all.
P2 has 8× the unknowns at the same ``n``: at n=10 (6859 unknowns) one 32-column run takes
~5 s and ``auto`` would compile 6859 columns (minutes); use ``n=5`` (729 unknowns).
``mesh=path`` reads a tetra mesh with meshio instead
(``n`` is then ignored).
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s

SETTINGS = {**scenes.WAVE_FINAL, "n": (10, s.positive_int), "T": (0.5, s.positive),
            "steps": (50, s.positive_int), "mesh": (None, s.optional_path)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "wave_3d")
    m = mesh.load(cfg["mesh"], dim=3) if cfg["mesh"] else mesh.unit_cube(cfg["n"])
    return scenes.wave("wave_3d", m, cfg)
