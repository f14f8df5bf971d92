"""Builders shared by the problem modules: a mesh and resolved settings in, a Problem out.

Problem modules stay a dozen readable lines: declare settings, make a mesh,
call one of these.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import scipy.sparse as sp
from skfem.models.poisson import mass

from ..fem.advection import cellular_flow, convection
from ..fem.forms import discretize
from ..inverse import default_inverse
from ..physics import Heat, Leapfrog, Wave
from . import settings as s
from .definition import Problem
from .sampling import PRIORS

#: settings every scene has
COMMON = {
    "element": ("P1", s.one_of("P1", "P2")),
    "T": (1.0, s.positive),
    "steps": (100, s.positive_int),
    "noise": (0.0, s.nonnegative),
    "prior": ("bumps", s.one_of(*PRIORS)),  # what x is drawn from (pdeinv.problem.sampling)
}


def prior(points, cfg: dict):
    """The scene's sampler ``(n, rng) -> (n, N)`` at ``points``: ``cfg['prior']`` (default ``bumps``)
    from :data:`pdeinv.problem.sampling.PRIORS`. Every prior draws over the unknowns' extent (widths and
    centres relative to their bounding box), so unknowns all at one point (``n=2`` of heat_1d leaves the
    midpoint) are refused, naming ``n`` (NaN fields and "array must not contain infs or NaNs" before)."""
    points = np.asarray(points)
    if points.size and not np.ptp(points, axis=1).any():
        count, name = points.shape[1], cfg.get("prior", "bumps")
        mesh = f"n={cfg['n']!r}" if "n" in cfg else "the mesh"
        raise ValueError(f"{mesh} is too coarse: it leaves {count} unknown{'s' if count != 1 else ''} at one "
                         f"point (after the boundary conditions): the prior {name!r} draws fields over the "
                         "unknowns' extent, and there is none; refine the mesh (a larger n)")
    return partial(PRIORS[cfg.get("prior", "bumps")], points)

HEAT = {**COMMON, "kappa": (0.01, s.positive), "scheme": ("be", s.one_of("be", "cn")),
        "backend": ("auto", s.one_of("auto", "steps", "modal", "dense", "svd")),
        # the modal form's relative cut: modes amplified by less than tol·max gain are dropped
        "tol": (1e-14, s.fraction)}

#: how a time-stepping operator is applied (pdeinv.physics.backends.compiled): 'auto' by the cost of a run
COMPILED = {"backend": ("auto", s.one_of("auto", "steps", "dense", "svd"))}

WAVE = {**COMMON, "c": (1.0, s.positive), **COMPILED}


def _leapfrog(mesh, disc, cfg):
    if cfg["element"] != "P1":
        raise ValueError(f"scheme='leapfrog' with element={cfg['element']!r}: leapfrog needs a lumped "
                         "mass, offered for 'P1' only; use element='P1' or scheme='newmark'")
    full = mass.assemble(disc.basis)  # lumped before condensation, on the same free unknowns
    lumped = sp.diags(np.asarray(full.sum(axis=1)).ravel()[disc.free])
    return Leapfrog(lumped, disc.K, c=cfg["c"], T=cfg["T"], steps=cfg["steps"])


#: wave time integrators for final-field scenes: name -> (mesh, disc, cfg) -> operator
WAVE_SCHEMES = {
    "newmark": lambda mesh, disc, cfg: Wave(disc.M, disc.K, c=cfg["c"], T=cfg["T"], steps=cfg["steps"],
                                                 dim=disc.dim),
    "leapfrog": _leapfrog,
}

#: settings of the final-field wave scenes (the sensor scene builds on Newmark's state step)
WAVE_FINAL = {**WAVE, "scheme": ("newmark", s.one_of(*WAVE_SCHEMES))}


def heat(name: str, mesh, cfg: dict) -> Problem:
    """Heat scene: θ-scheme final-field observation, homogeneous Dirichlet boundary; with
    ``cfg['reaction'] = r`` the reaction–diffusion ``M u' + (κK + rM) u = 0`` (still symmetric)."""
    disc = discretize(mesh, cfg["element"])
    C = cfg["reaction"] * disc.M if cfg.get("reaction") else None
    op = Heat(disc.M, disc.K, kappa=cfg["kappa"], T=cfg["T"], steps=cfg["steps"],
              scheme=cfg["scheme"], backend=cfg["backend"], measure=disc.measure, dim=disc.dim, C=C,
              tol=cfg["tol"])
    return Problem(name, disc, op, prior(disc.points, cfg), settings=cfg,
                   noise=cfg["noise"],
                   inverse_simulator=default_inverse(op, disc, noise=cfg["noise"]))


def heat_sensors(name: str, mesh, cfg: dict) -> Problem:
    """Heat scene observed at ``cfg['sensors']`` interior points every ``cfg['record_every']``
    steps; stepping, dense or SVD by the cost of a run (``cfg['backend']``)."""
    from ..fem import sensors as observe

    disc = discretize(mesh, cfg["element"])
    points = observe.place(mesh, cfg["sensors"], "inside")
    heat_op = Heat(disc.M, disc.K, kappa=cfg["kappa"], T=cfg["T"], steps=cfg["steps"],
                   scheme=cfg["scheme"], backend="steps", measure=disc.measure, dim=disc.dim)
    op = heat_op.sensors(observe.sensor_matrix(disc, points), cfg["record_every"]).compile(cfg["backend"],
                                                                                         disc.M)
    return Problem(name, disc, op, prior(disc.points, cfg),
                   settings={**cfg, "sensor_points": points}, noise=cfg["noise"],
                   inverse_simulator=default_inverse(op, disc, noise=cfg["noise"]))


def advection_diffusion(name: str, mesh, cfg: dict) -> Problem:
    """Heat scene with convection by the cellular flow of speed ``cfg['speed']``
    (:mod:`pdeinv.fem.advection`)."""
    disc = discretize(mesh, cfg["element"])
    C = convection(disc, cellular_flow(cfg["speed"]), cfg["kappa"])
    op = Heat(disc.M, disc.K, kappa=cfg["kappa"], T=cfg["T"], steps=cfg["steps"], scheme=cfg["scheme"],
              backend=cfg["backend"], measure=disc.measure, dim=disc.dim, C=C)
    return Problem(name, disc, op, prior(disc.points, cfg), settings=cfg, noise=cfg["noise"],
                   inverse_simulator=default_inverse(op, disc, noise=cfg["noise"]))


def wave(name: str, mesh, cfg: dict) -> Problem:
    """Wave scene: ``x = u₀``, ``v₀ = 0``, observe ``u(T)``; Dirichlet boundary.

    ``cfg['scheme']``: 'newmark' (default; implicit, no stability limit, local inverse
    by time reversal) or 'leapfrog' (explicit, lumped mass, refuses dt above its CFL
    limit; local inverse: the generic Tikhonov CG solve).
    """
    disc = discretize(mesh, cfg["element"])
    op = WAVE_SCHEMES[cfg.get("scheme", "newmark")](mesh, disc, cfg).compile(cfg["backend"], disc.M)
    return Problem(name, disc, op, prior(disc.points, cfg), settings=cfg,
                   noise=cfg["noise"],
                   inverse_simulator=default_inverse(op, disc, noise=cfg["noise"]))
