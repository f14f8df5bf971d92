"""Wave on (0, 1), fixed ends, v(0) = 0: recover u(0) from u(T).

Defaults: c = 1, T = 0.5 (a pulse travels half the domain), 64 P1 elements,
100 Newmark steps (dt = h/1.28: implicit, no CFL limit).
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s

SETTINGS = {**scenes.WAVE_FINAL, "n": (64, s.positive_int), "T": (0.5, s.positive)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "wave_1d")
    return scenes.wave("wave_1d", mesh.interval(cfg["n"]), cfg)
