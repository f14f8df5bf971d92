"""Photoacoustic tomography (PAT) model: recover the initial pressure u₀ from boundary sensors.

``M u'' + c² K u = 0`` on the unit square (or a mesh file), ``v₀ = 0``, Newmark
steps; ``sensors`` point sensors on the boundary ring record ``u`` every
``record_every`` steps (time series, record-major: ``y.reshape(B, R, n_s)``, see
:mod:`pdeinv.physics.propagator`).

**Boundary: natural (Neumann, sound-hard) by default.** With a Dirichlet
(pressure-release) wall the field is 0 on the boundary, so sensors must sit
inside; at distance ``h`` they would read ``≈ h ∂u/∂n`` — a signal that
vanishes under mesh refinement, making the data (and the conditioning) depend
on the mesh. On a natural boundary the sensors sit *on* the boundary and read an
``O(1)`` trace, independent of ``h``, and the reflecting cavity is a standard
PAT model (reverberant-cavity PAT: Cox, Arridge & Beard 2007). ``boundary=
'dirichlet'`` is offered too: a count of sensors is then placed one mean
boundary-edge length inside.

Defaults: c = 1, T = 1.5 (a wave crosses the diagonal √2), 32×32×2 P1 triangles
(1089 unknowns with Neumann), 96 steps (c·dt/h = 0.5), 64 sensors, every 2nd
step recorded (48 records, 3072 observations).

Inverse simulator: :func:`pdeinv.inverse.default_inverse` — the operator is compiled to its SVD
(``backend='auto'``), so the local inverse is the exact Tikhonov filter per singular value, with
the library's α (1e-20 relative to the largest ``g²``, :data:`pdeinv.inverse.NOISE_FREE_REL_ALPHA`;
noisy data go to a denoised target, :mod:`pdeinv.methods.targets`); ``alpha`` sets another relative α.
"""


import numpy as np

from pdeinv import mesh, observe, scenes
from pdeinv import settings as s
from pdeinv.fem.forms import discretize
from pdeinv.inverse import RelativeAlpha, default_inverse
from pdeinv.problem.definition import Problem

SETTINGS = {**scenes.WAVE, "n": (32, s.positive_int), "T": (1.5, s.positive),
            "steps": (96, s.positive_int), "mesh": (None, s.optional_path),
            "sensors": (64, observe.sensor_spec), "record_every": (2, s.positive_int),
            "boundary": ("neumann", s.one_of("neumann", "dirichlet")),
            "scheme": ("newmark", s.one_of(*scenes.WAVE_SCHEMES)),
            "alpha": (None, lambda v, name: None if v in (None, "", "None") else s.positive(v, name))}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "wave_sensors_2d")
    m = mesh.load(cfg["mesh"], dim=2) if cfg["mesh"] else mesh.unit_square(cfg["n"])
    dirichlet = cfg["boundary"] == "dirichlet"
    disc = discretize(m, cfg["element"], dirichlet=dirichlet)
    inset = float(np.mean(np.linalg.norm(np.diff(m.p[:, m.facets[:, m.boundary_facets()]], axis=1),
                                         axis=0))) if dirichlet else 0.0
    points = observe.place(m, cfg["sensors"], "boundary", inset=inset)
    wave = scenes.WAVE_SCHEMES[cfg["scheme"]](m, disc, cfg)  # newmark or leapfrog, same sensors
    op = wave.sensors(observe.sensor_matrix(disc, points), cfg["record_every"])
    op = op.compile(cfg["backend"], disc.M)  # stepping, dense or SVD by the cost of a run
    alpha = None if cfg["alpha"] is None else RelativeAlpha(cfg["alpha"])
    return Problem("wave_sensors_2d", disc, op, scenes.prior(disc.points, cfg),
                   settings={**cfg, "sensor_points": points}, noise=cfg["noise"],
                   inverse_simulator=default_inverse(op, disc, noise=cfg["noise"], alpha=alpha))
