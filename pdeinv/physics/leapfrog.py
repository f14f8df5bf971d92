"""Explicit leapfrog (central differences) for ``M_L u'' + c² K u = 0``, lumped mass, ``v₀ = 0``.

Second order in time, one sparse product per step and no solve (:class:`.schemes.Leapfrog`
has the step and its exact transpose). Stable iff ``c dt √λ_max < 2`` (CFL), ``λ_max``
the largest eigenvalue of ``K φ = λ M_L φ``: a ``dt`` at or above the limit is refused
with the smallest admissible number of steps (at the limit the error grows linearly,
above it exponentially). Newmark (:class:`pdeinv.physics.Wave`) has no limit; leapfrog wins
when many cheap steps beat a few solves (large meshes, moderate ``T``).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from .._checks import count, positive
from .backends.modes import largest_eigenvalue
from .propagator import FinalField, Propagator
from .schemes import Leapfrog as LeapfrogStep


class Leapfrog(Propagator):
    """Displacement at ``T`` after ``steps`` explicit leapfrog steps from ``(u₀, 0)``.

    ``M_lumped``: the lumped (diagonal, positive) mass on the free unknowns, e.g.
    ``discretize(mesh, 'P1', lumped=True).M``; ``K``: the stiffness.
    """

    def __init__(self, M_lumped, K, c=1.0, T=1.0, steps=100):
        m = np.asarray(sp.csr_matrix(M_lumped).diagonal(), dtype=float)
        off = sp.csr_matrix(M_lumped) - sp.diags(m)
        if (off.nnz and abs(off).max() > 0) or not np.all(m > 0):
            raise ValueError("Leapfrog needs a lumped mass: a diagonal matrix with positive entries "
                             "(discretize(mesh, 'P1', lumped=True).M)")
        self.K = sp.csr_matrix(K)
        self.c = positive(c, "c")
        self.t_end = positive(T, "T")
        steps = count(steps, "steps")
        dt = self.t_end / steps
        self.lam_max = largest_eigenvalue(sp.diags(m).tocsr(), self.K)
        self.dt_max = 2.0 / (self.c * math.sqrt(self.lam_max))
        if dt >= self.dt_max:
            need = math.floor(self.t_end / self.dt_max) + 1
            while self.t_end / need >= self.dt_max:  # rounding at the limit itself
                need += 1
            raise ValueError(
                f"dt = T/steps = {dt:.4g} is at or above the leapfrog stability limit "
                f"2/(c·√λ_max) = {self.dt_max:.4g} (c={self.c:g}, λ_max={self.lam_max:.4g}); "
                f"allowed: steps >= {need} for T={self.t_end:g}, or scheme='newmark' (no limit)")
        scheme = LeapfrogStep(1.0 / m, self.K, self.c, dt)
        super().__init__(scheme, FinalField(scheme.n, steps), steps, sp.diags(m).tocsr())

    def __repr__(self):
        return (f"Leapfrog(N={self.n_in}, c={self.c}, T={self.t_end}, steps={self.steps}, "
                f"dt/dt_max={self.dt / self.dt_max:.2f})")
