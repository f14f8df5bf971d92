"""Heat in the unit cube (or a tetra mesh file), u = 0 on the boundary: recover u(0) from sensor time series.

The 3-D version of heat_sensors_2d: ``sensors`` point sensors inside the cube (Halton
points, bases 2, 3, 5, in the inner 80% of the box; :func:`pdeinv.fem.sensors.interior_points`)
record u every ``record_every`` θ-scheme steps (record-major ``y.reshape(B, R, n_s)``).
``backend``: time stepping, or the run compiled once to a dense matrix or a truncated SVD
(``auto`` by the cost of a training run, :mod:`pdeinv.physics.backends.compiled`). Coordinates
``(n, 3)`` may be given instead of a count; points on the Dirichlet boundary are refused.

Defaults: κ = 0.05, T = 1 (diffusion length √(κT) ≈ 0.22, about the spacing of the
sensors), 8×8×8 cubes of 6 P1 tetrahedra (343 unknowns), 100 backward-Euler steps,
27 sensors, every 10th step recorded (10 records, 270 observations); ``auto`` compiles a
truncated SVD. Default CLI run (Adam, 1000 steps, one thread): x-error 0.41, 12 s of training.
"""


from pdeinv import mesh, observe, scenes
from pdeinv import settings as s

SETTINGS = {**{k: v for k, v in scenes.HEAT.items() if k != "backend"},
            "kappa": (0.05, s.positive), "n": (8, s.positive_int), "mesh": (None, s.optional_path),
            "sensors": (27, observe.sensor_spec), "record_every": (10, s.positive_int), **scenes.COMPILED}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "heat_sensors_3d")
    m = mesh.load(cfg["mesh"], dim=3) if cfg["mesh"] else mesh.unit_cube(cfg["n"])
    return scenes.heat_sensors("heat_sensors_3d", m, cfg)
