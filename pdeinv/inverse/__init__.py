"""Local inverse simulators ``P⁻¹_(x₀, y₀)(y)`` for SIP (Holl, Koltun, Thuerey 2022).

Each is a callable object ``inverse(y, x0)`` (numpy ``(B, n_out)``, ``(B, n_in)`` →
``(B, n_in)``) returning ``x0`` exactly when ``y = P x0``:

* :class:`ModalTikhonov` — heat, modal backend: filter ``g/(g²+α)`` per mode;
* :class:`TikhonovCG` — any linear operator: block PCG on ``(PᵀMP + αM)Δx = PᵀM(y − y₀)``;
* :class:`TimeReversal` / :class:`StateReversal` — wave: Newmark run backwards.

α is a number or a rule: :class:`Discrepancy` (Morozov), :class:`RelativeAlpha`.
:func:`default_inverse` picks one by what the operator can do (:mod:`pdeinv.physics.capabilities`).
"""

from __future__ import annotations

import numpy as np

from ..physics.capabilities import modal_basis, output_mass, reversible
from .alpha import Discrepancy, FixedAlpha, RelativeAlpha
from .cg import TikhonovCG
from .compiled import CompiledInverse
from .modal import ModalTikhonov, SpectralTikhonov
from .time_reversal import StateReversal, TimeReversal

#: default relative α without noise: cut-off at amplification 1e-5·max g. Measured with SIP on the
#: whitened linear default network (20 s heat_2d / 10 s heat_1d, one thread): α = 1e-8 gave test
#: x-errors 0.032 / 0.038, 1e-10 gave 0.026 / 0.034, 1e-12 gave 0.023 / 0.038 (float32 targets:
#: rounding 6e-8 amplified by 1/(2√α) starts to show). Before: 1e-8, cut-off at 1e-4·max g, so every
#: "well-observed" mode (g ≥ 1e-3·max g) is recovered with bias α/(g²+α) ≤ 1%
NOISE_FREE_REL_ALPHA = 1e-10


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


def default_inverse(op, disc=None, noise: float = 0.0, alpha=None):
    """The local inverse simulator for ``op``, chosen by capability (never by class).

    * reversible (``final_state`` and ``reverse``, e.g. :class:`~pdeinv.Wave`) →
      :class:`TimeReversal` (no α; exact at ``y₀``), as a :class:`CompiledInverse` matrix when
      the forward is compiled (dense or SVD) and it fits the budget;
    * a spectral basis (``op.modes``: the modal heat backend, or a compiled SVD) →
      :class:`SpectralTikhonov` (a filter per mode, Morozov's α in closed form);
    * anything else → :class:`TikhonovCG` with the input mass ``disc.M`` (``op.mass``, or
      the identity, if ``disc`` is None), the observation mass ``disc.M`` when ``op`` declares field
      observations (else Euclidean), and ``λ_max(P*P)`` from ``op.max_gain_squared()``
      when the operator knows it (else power iteration on first use).

    ``alpha`` defaults to :func:`default_alpha` ``(noise)``.
    """
    if reversible(op):  # compiled too when the forward is (its build is paid once, then cached)
        if getattr(op, "backend", None) is None:
            return TimeReversal(op)
        from ..physics.compiled import fingerprint

        try:
            return CompiledInverse(TimeReversal(op), op.n_out, op.n_in, fingerprint(op))
        except ValueError:  # over the dense budget
            return TimeReversal(op)
    rule = default_alpha(noise) if alpha is None else alpha
    if modal_basis(op) is not None:
        return SpectralTikhonov(op, rule)
    M = getattr(op, "mass", None) if disc is None else disc.M
    known = getattr(op, "max_gain_squared", None)
    return TikhonovCG(op, M, rule, M_out=output_mass(op, M), scale=known() if callable(known) else None)


__all__ = ["CompiledInverse", "Discrepancy", "FixedAlpha", "ModalTikhonov", "SpectralTikhonov",
           "RelativeAlpha",
           "StateReversal", "TikhonovCG", "TimeReversal", "default_alpha", "default_inverse"]
