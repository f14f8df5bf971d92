"""Builders of the nonlinear scenes (Allen–Cahn heat, sine-Gordon wave): a mesh and settings in, a
Problem out, as :mod:`pdeinv.problem.scenes` does for the linear ones.

``strength`` is the nonlinearity: ``r`` in ``f(u) = r (u³ − u)`` (Allen–Cahn) or ``s`` in
``g(u) = s sin u`` (sine-Gordon). At ``strength=0`` each operator is its linear scene's scheme
(heat: the same θ-scheme; wave: the leapfrog, ``scheme='leapfrog'`` of the linear wave scenes, at
the same ``steps``). ``amplitude`` scales the prior draws: a nonlinearity is only as strong as the
fields it acts on.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from skfem.models.poisson import mass

from ..fem.forms import discretize
from ..inverse import default_inverse
from ..physics.reaction import ReactionHeat
from ..physics.sine_gordon import SineGordon
from . import settings as s
from .definition import Problem
from .scenes import COMMON, prior


def _optional_steps(value, name):
    """``None`` (chosen: by the CFL limit, or every step kept) for None, '', 'auto' or 0; else an int >= 1."""
    if value in (None, "", "auto", 0, "0"):
        return None
    try:
        return s.positive_int(value, name)
    except ValueError as err:
        raise ValueError(f"{err} (or 0 / auto: chosen by pdeinv)") from None


#: Allen–Cahn heat: θ-scheme with Newton per step
ALLEN_CAHN = {**COMMON, "kappa": (0.01, s.positive), "scheme": ("be", s.one_of("be", "cn")),
              "strength": (1.0, s.nonnegative), "amplitude": (1.0, s.positive),
              "checkpoint_every": (None, _optional_steps)}

#: sine-Gordon wave: Störmer–Verlet, lumped mass; ``steps`` None: the fewest with dt ≤ cfl·dt_max
SINE_GORDON = {**COMMON, "c": (1.0, s.positive), "steps": (None, _optional_steps),
               "cfl": (0.5, s.positive), "strength": (100.0, s.nonnegative), "amplitude": (3.0, s.positive)}


def _scaled(sampler, amplitude: float):
    return sampler if amplitude == 1.0 else (lambda n, rng: amplitude * sampler(n, rng))


def allen_cahn(name: str, mesh, cfg: dict) -> Problem:
    """Allen–Cahn scene: ``x = u₀``, observe ``u(T)``, homogeneous Dirichlet boundary; local inverse:
    one regularized Gauss–Newton step (:class:`~pdeinv.inverse.gauss_newton.GaussNewtonInverse`) with
    ``rel_alpha = max(noise, 0.01)²``: noise-free, the rounding-level α of the linear scenes (1e-8 and
    below) over-amplified the step (one step from 0 on allen_cahn_1d: x-error 2.48 at 1e-8, 0.85 at
    1e-6, 0.50 at 1e-4; five steps 1.91 / 0.29 / 0.16)."""
    disc = discretize(mesh, cfg["element"])
    op = ReactionHeat(disc.M, disc.K, kappa=cfg["kappa"], T=cfg["T"], steps=cfg["steps"],
                      strength=cfg["strength"], scheme=cfg["scheme"],
                      checkpoint_every=cfg["checkpoint_every"])
    return Problem(name, disc, op, _scaled(prior(disc.points, cfg), cfg["amplitude"]), settings=cfg,
                   noise=cfg["noise"], inverse_simulator=default_inverse(op, disc, noise=cfg["noise"]))


def lumped_mass(disc):
    """The row-sum lumped mass on the free unknowns (lumped before condensation)."""
    full = mass.assemble(disc.basis)
    return sp.diags(np.asarray(full.sum(axis=1)).ravel()[disc.free]).tocsr()


def sine_gordon(name: str, mesh, cfg: dict) -> Problem:
    """Sine-Gordon scene: ``x = u₀``, ``v₀ = 0``, observe ``u(T)``; local inverse by reverse
    stepping from ``(y, v_T(x₀))`` (:class:`~pdeinv.inverse.TimeReversal`)."""
    if cfg["element"] != "P1":
        raise ValueError(f"element={cfg['element']!r}: the sine-Gordon scenes need a lumped mass, "
                         "offered for 'P1' only")
    disc = discretize(mesh, "P1")
    op = SineGordon(lumped_mass(disc), disc.K, c=cfg["c"], T=cfg["T"], steps=cfg["steps"],
                    strength=cfg["strength"], cfl=cfg["cfl"])
    return Problem(name, disc, op, _scaled(prior(disc.points, cfg), cfg["amplitude"]), settings=cfg,
                   noise=cfg["noise"], inverse_simulator=default_inverse(op, disc, noise=cfg["noise"]))
