"""Heat on the unit square (or a mesh file), u = 0 on the boundary: recover u(0) from sensor time series.

``sensors`` point sensors inside the domain record u every ``record_every``
θ-scheme steps (record-major ``y.reshape(B, R, n_s)``, see
:mod:`pdeinv.physics.propagator`). ``backend``: time stepping, or the
run compiled once to a dense matrix or a truncated SVD (no modal basis for records;
``auto`` by the cost of a training run, :mod:`pdeinv.physics.backends.compiled`). Given coordinates on the
Dirichlet
boundary are refused: the field is 0 there.

Defaults: κ = 0.05, T = 1 (diffusion length √(κT) ≈ 0.22, about the sensor
spacing, so every point of the domain reaches a sensor), 32×32×2 P1 triangles
(961 unknowns), 100 backward-Euler steps, 25 sensors (Halton points in the
inner 80% of the box), every 10th step recorded (10 records, 250 observations).

Inverse simulator: :func:`pdeinv.inverse.default_inverse` — with ``auto`` the run is compiled to
its SVD (134 singular values above 1e-12·max on the defaults), so the local inverse is the exact
Tikhonov filter per singular value (α 1e-20 relative; noisy data go to a denoised target,
:mod:`pdeinv.methods.targets`). Measured on the defaults (8 bump samples from x₀ = 0, noise-free): 0.9 ms,
relative L² error 0.040 — 25 sensors see the smooth part only. With ``backend='steps'`` it is a
Tikhonov-regularized block-CG solve on ``(PᵀP + αM)Δx = Pᵀ(y − y₀)`` instead.
"""

from pdeinv import mesh, observe, scenes
from pdeinv import settings as s

SETTINGS = {**{k: v for k, v in scenes.HEAT.items() if k != "backend"},
            "kappa": (0.05, s.positive), "n": (32, s.positive_int), "mesh": (None, s.optional_path),
            "sensors": (25, observe.sensor_spec), "record_every": (10, s.positive_int), **scenes.COMPILED}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "heat_sensors_2d")
    m = mesh.load(cfg["mesh"], dim=2) if cfg["mesh"] else mesh.unit_square(cfg["n"])
    return scenes.heat_sensors("heat_sensors_2d", m, cfg)
