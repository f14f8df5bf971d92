"""Wave on the unit square (or a mesh file), u = 0 on the boundary, v(0) = 0: recover u(0) from u(T).

Defaults: c = 1, T = 0.5, 32×32×2 P1 triangles (961 unknowns), 50 Newmark steps.
``mesh=path`` reads a triangle mesh with meshio instead (``n`` is then ignored).
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s

SETTINGS = {**scenes.WAVE_FINAL, "n": (32, s.positive_int), "T": (0.5, s.positive),
            "steps": (50, s.positive_int), "mesh": (None, s.optional_path)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "wave_2d")
    m = mesh.load(cfg["mesh"], dim=2) if cfg["mesh"] else mesh.unit_square(cfg["n"])
    return scenes.wave("wave_2d", m, cfg)
