"""Sine-Gordon wave on the unit square, u = 0 on the boundary, v(0) = 0: recover u(0) from u(T).

As sine_gordon_1d (strength s = 100, amplitude 3, explicit Störmer–Verlet, steps from the
stability limit) on 32×32×2 P1 triangles (961 unknowns) with T = 0.5 as wave_2d. ``mesh=path``
reads a triangle mesh instead.
"""

from pdeinv import mesh, nonlinear_scenes
from pdeinv import settings as s

SETTINGS = {**nonlinear_scenes.SINE_GORDON, "n": (32, s.positive_int), "T": (0.5, s.positive),
            "mesh": (None, s.optional_path)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "sine_gordon_2d")
    m = mesh.load(cfg["mesh"], dim=2) if cfg["mesh"] else mesh.unit_square(cfg["n"])
    return nonlinear_scenes.sine_gordon("sine_gordon_2d", m, cfg)
