"""What a local inverse simulator is, and the one optional capability a caller may use.

**contract** (DESIGN.md, "The local-inverse contract"): a local inverse ``P⁻¹_(x₀, y₀)`` is a
callable ``inverse(y, x0) -> x̃`` (numpy ``(B, n_out)``, ``(B, n_in)`` → ``(B, n_in)``) with

    inverse(P x₀, x₀) = x₀            (to rounding, for every x₀),

i.e. ``x̃ = x₀ + Δx`` with ``Δx`` a (regularized) inverse of the residual ``y − P x₀``; any
regularization acts on the change ``Δx``, never on ``x̃`` itself. SIP relies on it: its update
``x̃ = P⁻¹_(x, Px)(Px + η(y* − Px))`` is then a step from the current prediction ``x``, and the
training fixed point is where the residual vanishes (Holl, Koltun, Thuerey 2022, §3). An inverse
that ignored ``x₀`` would make SIP a regression onto one fixed closed-form target.

:class:`ReusesForward` is the capability of an inverse whose first act is computing ``y₀ = P x₀``:
SIP has computed it already (for its loss), and passes it, saving one forward call per step.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class ReusesForward(Protocol):
    """A local inverse that accepts ``y₀ = P x₀`` from a caller who has it.

    ``inverse.local(y, x0, y0)`` equals ``inverse(y, x0)`` when ``y0`` is ``op.forward(x0)`` of the
    operator the inverse was built on (the residual ``y − y₀`` is then exactly zero at ``y = y₀``);
    it costs one forward call fewer. Declared by :class:`~pdeinv.inverse.SpectralTikhonov`,
    :class:`~pdeinv.inverse.TikhonovCG` and :class:`~pdeinv.inverse.decoder.DecoderTikhonov`.
    """

    def __call__(self, y, x0) -> np.ndarray: ...

    def local(self, y, x0, y0) -> np.ndarray: ...
