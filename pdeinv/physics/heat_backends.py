"""Backends of the heat propagator ``P = (A⁻¹B)ⁿ`` and the rule that picks one.

Both act on float64 ``(B, N)`` arrays and implement ``forward`` and ``adjoint``
of the *same* discrete map; they agree to the modal tolerance.
"""

from __future__ import annotations

import math

import numpy as np

from ..cache import cached
from . import modes as _modes
from .compiled import Spectral, build, fingerprint, plan
from .modes import DENSE_MAX, TooManyModes, largest_eigenvalue, lowest_modes
from .propagator import FinalField, Propagator


def amplification(z, theta: float):
    """Per-step growth factor ``r(z) = (1 − (1−θ) z) / (1 + θ z)`` of mode ``z = dt κ λ``."""
    return (1.0 - (1.0 - theta) * z) / (1.0 + theta * z)


class Stepping:
    """``n`` θ-steps with one factorization of ``A`` (``heat.stepper``); batch columns solved together.

    forward: ``u ← A⁻¹(B u)`` n times;  adjoint: ``r ← Bᵀ(A⁻ᵀ r)`` n times (:mod:`.propagator`).
    """

    name = "steps"

    def __init__(self, heat):
        self.run = Propagator(heat.stepper, FinalField(heat.n_in, heat.steps), heat.steps, heat.M)
        self.forward, self.adjoint = self.run._forward, self.run._adjoint


class Modal(Spectral):
    """Truncated modal propagator ``P = Φ diag(g) Φᵀ M``, ``g = r(dtκλ)ⁿ``.

    Keeps the modes with ``|g| ≥ tol·max|g|`` (compared in logs, so nothing
    underflows before the comparison). forward: ``((X MΦ) g) Φᵀ``;
    adjoint: ``((R Φ) g) (MΦ)ᵀ``. For Crank–Nicolson ``|r| → 1`` as ``z → ∞``:
    if the highest mode would still be kept the truncation is not exact and a
    ``ValueError`` says so.

    The modes come from one block Krylov eigensolve sized by Weyl's count at the cut-off
    plus a margin (:func:`.modes.lowest_modes`), and are kept in the disk cache
    (:mod:`pdeinv.cache`, kind 'modal', key: M, K and every setting that decides
    which modes are kept); ``cache=False`` (or ``PDEINV_NO_CACHE=1``) recomputes.
    """

    name = "modal"

    def __init__(self, heat, cache: bool = True):
        log_tol = math.log(heat.tol)

        def log_g(lam):  # log|r(dtκλ)ⁿ|, safe where r underflows or vanishes
            r = np.abs(amplification(heat.dt * heat.kappa * np.asarray(lam), heat.theta))
            return heat.steps * np.log(np.maximum(r, 1e-300))

        if heat.theta < 1.0:
            lmax = largest_eigenvalue(heat.M, heat.K)
            if log_g(lmax) >= log_tol:
                raise ValueError(
                    f"Crank–Nicolson barely damps the highest mode (|r|ⁿ = "
                    f"{np.exp(log_g(lmax)):.1e} ≥ tol={heat.tol}): the modal backend "
                    "would need all modes; use backend='steps' or scheme='be'"
                )
        # modes to ask for: Weyl's count at the cut-off |r(dtκλ)|ⁿ = tol, plus 10% and 10
        rho = heat.tol ** (1.0 / heat.steps)
        z_cut = max(1.0 - rho, 0.0) / (heat.theta * rho + (1.0 - heat.theta))
        k_guess = math.ceil(1.1 * weyl_count(heat, z_cut / (heat.dt * heat.kappa)) + 10)

        def build():  # the lowest mode is the least damped one (|r| decreases on the damped branch)
            lam, Phi = lowest_modes(heat.M, heat.K, log_g, log_tol, k=k_guess)
            return {"lam": lam, "Phi": Phi}

        N = heat.M.shape[0]
        settings = {"dt": heat.dt, "kappa": heat.kappa, "theta": heat.theta, "steps": heat.steps,
                    "tol": heat.tol, "dense": N <= _modes.DENSE_MAX, "k": k_guess, "method": "block-krylov/1"}

        def verify(a):
            lam, Phi = a.get("lam", np.zeros(0)), a.get("Phi", np.zeros((0, 0)))
            if lam.ndim != 1 or len(lam) == 0 or Phi.shape != (N, len(lam)):
                return f"Phi of shape {Phi.shape} for {lam.shape} eigenvalues and {N} unknowns"

        got = cached("modal", {"M": heat.M, "K": heat.K, "settings": settings}, build, verify, cache)
        self.lam, self.Phi = got["lam"], np.ascontiguousarray(got["Phi"])
        self.g = heat.amplification(self.lam)
        self.MPhi = np.ascontiguousarray(heat.M @ self.Phi)
        self.n_total = heat.M.shape[0]
        # the spectral basis (compiled.Spectral applies it): P = out diag(g) Inᵀ, In = MΦ, out = synth = Φ
        self.proj, self.out, self.synth, self.mass_out = self.MPhi, self.Phi, self.Phi, heat.M
        self.In = self.MPhi



def _compiled(kind):
    def make(heat):
        run = Stepping(heat).run
        return build(kind, run._forward, heat.n_in, heat.n_in, heat.M, heat.M, fingerprint(run),
                     adjoint=run._adjoint)
    return make


BACKENDS = {"steps": Stepping, "modal": Modal, "dense": _compiled("dense"), "svd": _compiled("svd")}

#: a dense N×k product runs this many times more flops per second than a sparse
#: triangular solve on our machines (BLAS vs SuperLU's scalar loops); conservative
BLAS_ADVANTAGE = 4.0


def weyl_count(heat, lam: float) -> float:
    """Weyl's law: about how many eigenvalues of the Laplacian lie below ``lam``.

    ``N(λ) ≈ ω_d |Ω| λ^{d/2} / (2π)^d`` (``ω_d`` the unit ball's volume): 1-D ``|Ω|√λ/π``,
    2-D ``|Ω|λ/(4π)``, 3-D ``|Ω|λ^{3/2}/(6π²)`` (leading terms; over-estimates for Dirichlet).
    """
    if heat.dim not in WEYL:
        raise ValueError(f"dim={heat.dim!r} is not supported by Weyl's law here; expected 1, 2 or 3")
    return heat.measure * WEYL[heat.dim] * lam ** (heat.dim / 2) + 1


#: Weyl constants ``ω_d/(2π)^d`` per dimension
WEYL = {1: 1 / math.pi, 2: 1 / (4 * math.pi), 3: 1 / (6 * math.pi**2)}


def choose(heat):
    """Pick the cheaper backend for one application of ``P`` per batch column.

    stepping ≈ n·(2·fill(LU) + 2·nnz(B)) flops;  modal ≈ 4·N·k / BLAS_ADVANTAGE, with
    ``k = min(N, Weyl's count at the cut-off |r(dtκλ)|ⁿ = tol)``. Modal is tried, for a
    symmetric operator only (no convection), if ``k ≤ N/2`` or the mesh is small enough
    for a dense eigendecomposition (all modes, ``N ≤ DENSE_MAX``: Weyl over-estimates on
    coarse meshes, and a dense N×N product still beats stepping there); if building it
    fails (too many modes, CN not truncatable) we step.
    """
    N = heat.n_in
    # cut-off eigenvalue: solve |r(z)|^n = tol for z on the damped branch (z ≤ 2/(1-θ) region)
    rho = heat.tol ** (1.0 / heat.steps)
    th = heat.theta
    z_cut = (1.0 - rho) / (th * rho + (1.0 - th))  # r(z) = rho, decreasing branch
    lam_cut = z_cut / (heat.dt * heat.kappa)
    k_est = min(weyl_count(heat, lam_cut), N)
    stepping = Stepping(heat)
    fill = getattr(heat.stepper.lu, "fill", 10 * heat.M.nnz)
    cost_steps = heat.steps * (2 * fill + 2 * heat.stepper.B.nnz)
    if not heat.symmetric:  # no modal basis: stepping, dense or SVD by the cost of a run
        kind, why = plan(cost_steps, N, N)
        return (stepping if kind == "steps" else BACKENDS[kind](heat)), f"{why}; not symmetric: no modes"
    cost_modal = 4 * N * k_est / BLAS_ADVANTAGE
    why = (f"modal≈{cost_modal:.3g} flops/column with ~{k_est:.0f} of {N} modes (Weyl) vs "
           f"steps≈{cost_steps:.3g}")
    if (k_est <= N / 2 or N <= DENSE_MAX) and cost_modal < cost_steps:
        try:
            modal = Modal(heat)
        except (TooManyModes, ValueError) as err:
            return stepping, f"auto: steps ({why}; modal refused: {err})"
        return modal, f"auto: modal, {modal.k} modes kept ({why})"
    return stepping, f"auto: steps ({why})"
