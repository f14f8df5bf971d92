"""Explicit leapfrog (central differences) for ``M_L u'' + c² K u = 0`` with a lumped mass.

With ``A = M_L⁻¹ K`` (``M_L`` the diagonal lumped mass), ``q = (c dt)²`` and ``v₀ = 0``,

    u¹ = u⁰ − ½ q A u⁰,        uⁿ⁺¹ = 2uⁿ − uⁿ⁻¹ − q A uⁿ,

second order in time, one sparse product per step and no solve. The step and its
exact transpose are :class:`.schemes.Leapfrog` (``u¹`` is the general step from the
fictitious ``u⁻¹ = u¹``); :mod:`.propagator` owns the loop, so sensor records
come for free (``Leapfrog(...).sensors(S, k)``).

Stability (CFL): the scheme is stable iff ``c dt √λ_max < 2``, ``λ_max`` the
largest eigenvalue of ``K φ = λ M_L φ``; a ``dt`` at or above the limit is
refused with the limit and the smallest admissible number of steps (at the
limit the error grows linearly, above it exponentially). Newmark
(:class:`pdeinv.Wave`) has no limit; use leapfrog when many cheap steps beat
a few solves, e.g. on large meshes with a moderate ``T``.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from .._checks import count, positive
from .modes import largest_eigenvalue
from .observation import FinalField
from .propagator import Propagator
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
