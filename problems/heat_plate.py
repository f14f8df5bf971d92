"""Heat on a plate with a hole, read from ``problems/meshes/plate.msh``: recover u(0) from u(T).

The plate is the unit square with an off-centre circular hole (centre (0.42,
0.56), radius 0.2; made by ``problems/meshes/make_plate.py``, 704 nodes, 1280
triangles), refined ``refine`` times uniformly. Boundary conditions chosen by
geometry: u = 0 on the **outer** boundary (the boundary loop through the
left-most node), natural Neumann (insulated) on the hole — heat can only leave
through the outer edge. ``mesh=path`` reads another file; its outer loop is
found the same way and all other boundary loops are insulated.

Defaults: κ = 0.01, T = 1, 100 backward-Euler steps, P1, refine = 1 (2687
nodes, about 2560 unknowns); ``refine=0`` for tests. Inverse simulator:
:func:`pdeinv.inverse.default_inverse` (modal Tikhonov when the modal backend
is chosen, else block CG).
"""

from functools import partial
from pathlib import Path

import numpy as np

from pdeinv import mesh, scenes
from pdeinv import settings as s
from pdeinv.forms import discretize
from pdeinv.inverse import default_inverse
from pdeinv.observe import boundary_loops
from pdeinv.physics import Heat
from pdeinv.problem import Problem
from pdeinv.sampling import gaussian_bumps

PLATE = Path(__file__).resolve().parent / "meshes" / "plate.msh"


SETTINGS = {**scenes.HEAT, "refine": (1, s.nonnegative_int), "mesh": (None, s.optional_path)}


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
    m = mesh.load(cfg["mesh"] or PLATE)
    if cfg["refine"]:
        m = m.refined(cfg["refine"])
    basis = discretize(m, cfg["element"], dirichlet=False).basis
    disc = discretize(m, cfg["element"], dirichlet=outer_dirichlet_dofs(basis))
    op = Heat(disc.M, disc.K, kappa=cfg["kappa"], T=cfg["T"], steps=cfg["steps"],
              scheme=cfg["scheme"], backend=cfg["backend"], measure=disc.measure, dim=disc.dim)
    return Problem("heat_plate", disc, op, partial(gaussian_bumps, disc.points), settings=cfg,
                   noise=cfg["noise"], inverse_simulator=default_inverse(op, disc, noise=cfg["noise"]))
