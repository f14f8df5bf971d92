"""Heat on a plate with a hole, read from ``problems/meshes/plate.msh``: recover u(0) from u(T).

The plate is the unit square with an off-centre circular hole (centre (0.42,
0.56), radius 0.2; made by ``problems/meshes/make_plate.py``, 704 nodes, 1280
triangles), refined ``refine`` times uniformly. Boundary conditions by the
file's boundary tags: u = 0 on the boundaries named in ``dirichlet`` (default
``outer``; the file also names ``hole``), natural Neumann (insulated) on the
rest — by default heat can only leave through the outer edge.
``dirichlet=outer,hole`` (or a list) fixes both. ``mesh=path`` reads another
file; if it has no tags, ``dirichlet=outer`` falls back to geometry (the
boundary loop through the left-most node) and every other loop is insulated.

Defaults: κ = 0.01, T = 1, 100 backward-Euler steps, P1, refine = 1 (2687
nodes, about 2560 unknowns); ``refine=0`` for tests. Inverse simulator:
:func:`pdeinv.inverse.default_inverse` (modal Tikhonov when the modal backend
is chosen, else block CG).
"""

from pathlib import Path

import numpy as np

from pdeinv import mesh, scenes
from pdeinv import settings as s
from pdeinv.fem.forms import discretize
from pdeinv.fem.sensors import boundary_loops
from pdeinv.inverse import default_inverse
from pdeinv.physics import Heat
from pdeinv.problem.definition import Problem

PLATE = Path(__file__).resolve().parent / "meshes" / "plate.msh"


def names(value, name):
    """Boundary names, given as a comma-separated string or a list of strings (at least one),
    kept as the comma-separated string (JSON-friendly in metrics and checkpoints)."""
    items = value.split(",") if isinstance(value, str) else value
    ok = isinstance(items, (list, tuple)) and items and all(isinstance(v, str) and v.strip() for v in items)
    if not ok:
        raise ValueError(f"{name}={value!r} is not allowed; expected names like 'outer' or 'outer,hole'")
    return ",".join(v.strip() for v in items)


SETTINGS = {**scenes.HEAT, "refine": (1, s.nonnegative_int), "mesh": (None, s.optional_path),
            "dirichlet": ("outer", names)}


def outer_dirichlet_dofs(basis) -> np.ndarray:
    """DOFs on the boundary loop through the left-most node (the outer boundary of a plate)."""
    m = basis.mesh
    loops = boundary_loops(m)
    outer = next(loop for loop in loops if np.argmin(m.p[0]) in set(loop.tolist()))
    on_outer = np.isin(m.facets, outer).all(axis=0)
    facets = np.intersect1d(m.boundary_facets(), np.flatnonzero(on_outer))
    return basis.get_dofs(facets).all()


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "heat_plate")
    m = mesh.refined(mesh.load(cfg["mesh"] or PLATE, dim=2), cfg["refine"])  # refused first if too large
    if m.boundaries or cfg["dirichlet"] != "outer":
        fixed = cfg["dirichlet"].split(",")  # names, checked against the file's tags by discretize
    else:
        fixed = outer_dirichlet_dofs(discretize(m, cfg["element"], dirichlet=False).basis)
    disc = discretize(m, cfg["element"], dirichlet=fixed)
    op = Heat(disc.M, disc.K, kappa=cfg["kappa"], T=cfg["T"], steps=cfg["steps"],
              scheme=cfg["scheme"], backend=cfg["backend"], measure=disc.measure, dim=disc.dim)
    return Problem("heat_plate", disc, op, scenes.prior(disc.points, cfg), settings=cfg,
                   noise=cfg["noise"], inverse_simulator=default_inverse(op, disc, noise=cfg["noise"]))
