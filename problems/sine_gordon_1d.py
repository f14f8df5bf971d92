"""Sine-Gordon wave on (0, 1), fixed ends, v(0) = 0: recover u(0) from u(T).

``M_L u'' + c² K u + M_L s sin u = 0`` by Störmer–Verlet with the lumped mass
(:class:`pdeinv.physics.sine_gordon.SineGordon`), explicit, ``steps`` chosen for dt = ½ of the
stability limit unless given. Defaults: c = 1, T = 1/3 (as wave_1d: no mode hidden), 64 P1
elements, ``strength`` s = 100 and prior ``amplitude`` 3 (the bumps prior times 3: fields of a few
radians, where sin u is far from u). There the linearization at 0 (Klein–Gordon ``u'' = c²Δu − s u``)
misses P(x) by 27 % (median ‖P(x) − P'(0)x‖/‖P(x)‖ over 64 draws). ``strength=0`` with the same
``steps`` is wave_1d with ``scheme=leapfrog``. Local inverse: reverse stepping.
"""

from pdeinv import mesh, nonlinear_scenes
from pdeinv import settings as s

SETTINGS = {**nonlinear_scenes.SINE_GORDON, "n": (64, s.positive_int), "T": (1 / 3, s.positive)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "sine_gordon_1d")
    return nonlinear_scenes.sine_gordon("sine_gordon_1d", mesh.interval(cfg["n"]), cfg)
