"""Heat in a cube with a cold spherical cavity (``problems/meshes/cavity.msh``): recover u(0) from u(T).

The cube is the unit cube with an off-centre spherical cavity (centre (0.45, 0.55,
0.5), radius 0.25; made by ``problems/meshes/make_cavity.py``, 1308 nodes, 6480
tetrahedra), refined ``refine`` times uniformly. Boundary conditions by the file's
boundary tags: u = 0 on the boundaries named in ``dirichlet`` (default ``cavity``; the
file also names ``outer``), natural Neumann (insulated) on the rest. The default is a
block insulated on the outside and cooled through the cavity: heat can only leave
through the cavity, so the field far from it (the cube's corners) is smoothed but
barely damped, and the observation sees the whole block — with u = 0 on the outer
faces too (``dirichlet=outer,cavity``) the thin shell between the faces and the cavity
would kill most of what starts there. ``mesh=path`` reads another tetra mesh file with
these tags.

Defaults: κ = 0.01, T = 1, 100 backward-Euler steps, P1 (the settings of heat_2d),
refine = 0: 1090 unknowns; the lowest eigenvalue is 7.2 (amplification 0.93), 183 of
the 1090 modes keep an amplification ≥ 1e-3, 116 keep ≥ 1e-2. ``backend='auto'`` picks
the modal operator (all modes by one dense eigendecomposition, 778 kept above 1e-14).
Default CLI run (Adam, 1000 steps, one thread): x-error 0.18 (worst next to the cavity,
where u = 0 erases what starts there), 32 s of CPU (the default network is a 1090×1090
whitened linear map). Inverse simulator:
:func:`pdeinv.inverse.default_inverse`.
"""

from pathlib import Path

from pdeinv.problems.heat_plate import names

from pdeinv import mesh, scenes
from pdeinv import settings as s
from pdeinv.fem.forms import discretize
from pdeinv.inverse import default_inverse
from pdeinv.physics import Heat
from pdeinv.problem.definition import Problem

CAVITY = Path(__file__).resolve().parent / "meshes" / "cavity.msh"

SETTINGS = {**scenes.HEAT, "refine": (0, s.nonnegative_int), "mesh": (None, s.optional_path),
            "dirichlet": ("cavity", names)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "heat_cavity_3d")
    m = mesh.refined(mesh.load(cfg["mesh"] or CAVITY, dim=3), cfg["refine"])  # refused first if too large
    disc = discretize(m, cfg["element"], dirichlet=cfg["dirichlet"].split(","))
    op = Heat(disc.M, disc.K, kappa=cfg["kappa"], T=cfg["T"], steps=cfg["steps"],
              scheme=cfg["scheme"], backend=cfg["backend"], measure=disc.measure, dim=disc.dim)
    return Problem("heat_cavity_3d", disc, op, scenes.prior(disc.points, cfg), settings=cfg,
                   noise=cfg["noise"], inverse_simulator=default_inverse(op, disc, noise=cfg["noise"]))
