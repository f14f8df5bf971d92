"""Local inverse simulators ``P⁻¹_(x₀, y₀)(y)`` for SIP (Holl, Koltun, Thuerey 2022).

Each is a callable object ``inverse(y, x0)`` (numpy ``(B, n_out)``, ``(B, n_in)`` →
``(B, n_in)``) returning ``x0`` exactly when ``y = P x0`` (the local-inverse contract,
:mod:`.protocol`; ``tests/test_local_contract.py`` checks it for every one shipped):

* :class:`ModalTikhonov` — heat, modal backend: filter ``g/(g²+α)`` per mode;
* :class:`TikhonovCG` — any linear operator: block PCG on ``(PᵀMP + αM)Δx = PᵀM(y − y₀)``;
* :class:`TimeReversal` / :class:`StateReversal` — wave: Newmark run backwards;
* :class:`~.decoder.DecoderTikhonov` — SIP's default for a network with a fixed decoder ``D``: the
  Tikhonov change in ``span D``.

Those whose first act is ``y₀ = P x₀`` declare :class:`ReusesForward` (``local(y, x0, y0)``): SIP
passes the ``P x`` it has computed for its loss.

α is a number or a rule: :class:`Discrepancy` (Morozov), :class:`RelativeAlpha`.
:func:`default_inverse` picks one by what the operator can do (:mod:`pdeinv.physics.capabilities`).
"""

from __future__ import annotations

import numpy as np

from ..physics.backends.compiled import spectral_basis
from ..physics.capabilities import output_mass, reversible
from ..physics.nonlinear import is_linear
from ..physics.propagator import chosen
from .alpha import Discrepancy, FixedAlpha, RelativeAlpha
from .cg import TikhonovCG
from .gauss_newton import GaussNewtonInverse
from .modal import ModalTikhonov, SpectralTikhonov
from .protocol import ReusesForward
from .time_reversal import StateReversal, TimeReversal

#: default relative α without noise: cut-off at amplification 1e-10·max g, from float64 rounding: the
#: residual ``y − P x₀`` carries rounding ~1e-16·‖y‖, amplified by at most ``1/(2√α)`` = 5e9 (relative
#: to max g), i.e. ~5e-7 of the field, below what any scene's accuracy asks (float64 networks; a float32
#: target's rounding 6e-8 would need 1e-10).
NOISE_FREE_REL_ALPHA = 1e-20


def default_alpha(noise: float = 0.0) -> RelativeAlpha:
    """``α = max(δ, 1e-5)² · max g²``: the filter cut-off ``g = √α`` where signal meets noise.

    A mode amplified by ``g`` carries ``g·x_k`` into ``y``, against relative noise
    ``δ·max g`` (roughly): below ``g ≈ δ·max g`` the data say nothing about
    ``x_k``, so the filter ``g/(g²+α)`` should switch off there, i.e.
    ``α = δ²·max g²``. SIP itself feeds the inverse exact ``y = P x`` plus a
    step toward the (possibly noisy) target; for noise-free data the floor
    ``1e-5`` keeps the amplification of rounding bounded by ``1/(2√α)``.
    For a data-driven choice per sample use :class:`Discrepancy` instead.
    """
    return RelativeAlpha(max(float(noise), np.sqrt(NOISE_FREE_REL_ALPHA)) ** 2)


#: CG's relative residual in the nonlinear local inverse: an inexact Gauss–Newton step (Eisenstat–Walker's
#: constant forcing term 0.1) — the linearization itself is off by far more than 1e-6 away from ``x₀``.
#: SIP on allen_cahn_1d, 10 full-batch steps: 4 CG iterations and 6.8 s per step, x-error 0.328, against
#: 10–12 iterations, 14 s per step and 0.333 at rtol 1e-6.
GN_RTOL = 0.1


def default_inverse(op, disc=None, noise: float = 0.0, alpha=None):
    """The local inverse simulator for ``op``, chosen by capability (never by class), after ``op``'s
    backend (a time-stepping operator no one chose one for is compiled by ``auto`` first,
    :func:`pdeinv.physics.propagator.chosen`).

    * a spectral basis (``op.modes``: the modal heat backend, or a compiled SVD), or a compiled
      dense forward (``op.backend.P``, whose SVD in the problem's norms is then computed on the
      first call, :class:`~pdeinv.physics.backends.compiled.LazySVD`) → :class:`SpectralTikhonov`: the exact
      Tikhonov filter per singular value (Morozov's α in closed form);
    * else reversible (declared by the scheme: :class:`~pdeinv.physics.Wave`,
      :class:`~pdeinv.physics.Leapfrog`)
      → :class:`TimeReversal` (no α; exact at ``y₀``; two stepping runs).

    Why the filter wins where both exist: time reversal from ``(y, v_T(x₀))`` changes each mode
    by ``cos(ω_k T)·Δy_k``, i.e. it applies ``Pᵀ`` (scaled by the singular value, not by its
    inverse): SIP with it is a gradient step in disguise (wave_2d: x-error 0.13 against the filter's
    0.0014). Time reversal stays the inverse of
    a time-stepping wave forward (``backend='steps'``), where an SVD would need the dense map;
    * a nonlinear operator (declared ``linear = False``) → :class:`~.gauss_newton.GaussNewtonInverse`,
      ``rel_alpha = max(noise, 0.01)²`` (:func:`pdeinv.nonlinear_scenes.allen_cahn` says why), CG to
      :data:`GN_RTOL` (an inexact Gauss–Newton step);
    * anything else → :class:`TikhonovCG` with the input mass ``disc.M`` (``op.mass``, or
      the identity, if ``disc`` is None), the observation mass ``disc.M`` when ``op`` declares field
      observations (else Euclidean), and ``λ_max(P*P)`` from ``op.max_gain_squared()``
      when the operator knows it (else power iteration on first use).

    ``alpha`` defaults to the rounding level :func:`default_alpha` ``(0)`` where ``op`` has a spectral
    basis: with noisy observations the trainer then fits a denoised target (:mod:`pdeinv.methods.targets`),
    the inverse sees no noise, and since the fixed point of SIP with any Tikhonov inverse is the
    least-squares solution of its target (``Pᵀ(t − Px) = 0``) α only sets the speed: α → 0 is
    Gauss–Newton, one step. Without a spectral basis no target is fitted, the inverse's α is the
    only regularization of each step, and it defaults to :func:`default_alpha` ``(noise)`` (the
    iteration then semi-converges: a stopping rule ends it, :mod:`pdeinv.training.stopping`).
    """
    M = op.mass if disc is None else disc.M
    chosen(op, M)  # an operator no one chose a backend for: compiled by auto, as training will use it
    modes = spectral_basis(op, M)  # a compiled dense forward: its SVD, computed on the first call
    if modes is not None:
        return SpectralTikhonov(op, default_alpha(0.0) if alpha is None else alpha, modes=modes)
    rule = default_alpha(noise) if alpha is None else alpha
    if reversible(op):
        return TimeReversal(op)
    if not is_linear(op):  # no matrix to solve with: a regularized Gauss–Newton step through jvp/vjp
        return GaussNewtonInverse(op, M, rel_alpha=max(float(noise), 1e-2) ** 2, rtol=GN_RTOL)
    known = op.max_gain_squared  # declared (a callable) or None
    return TikhonovCG(op, M, rule, M_out=output_mass(op, M), scale=None if known is None else known())


__all__ = ["Discrepancy", "FixedAlpha", "GN_RTOL", "ModalTikhonov", "SpectralTikhonov",
           "RelativeAlpha", "ReusesForward",
           "StateReversal", "TikhonovCG", "TimeReversal", "default_alpha", "default_inverse"]
