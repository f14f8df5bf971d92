"""Learning-rate schedules of a counted fit: the factor ``s(t, T)`` the fit's lr is multiplied by at step
``t`` of ``T`` (:class:`~pdeinv.nets.refine.PriorFit`'s ``schedule``).

:class:`Cosine` is the half-cosine of Loshchilov & Hutter (2017) without restarts,

    s(t, T) = floor + (1 − floor) · ½ (1 + cos(π t / T)),

from 1 at the first step to ``floor`` at the last: the budget is a count, so the schedule knows where
it ends, and the small steps at its end average out the noise of the mini-batch gradients that a constant
lr keeps to the last step. :class:`Constant` (the default) is ``s ≡ 1``: the prior fits that a count ends
before their plateau (heat_boxes) lose more by the smaller steps than they gain by the averaging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Constant:
    """``s(t, T) = 1``: the lr as given at every step."""

    def __call__(self, step: int, steps: int) -> float:
        return 1.0


@dataclass(frozen=True)
class Cosine:
    """``s(t, T) = floor + (1 − floor) · ½ (1 + cos(π t / T))`` (module docstring)."""

    floor: float = 0.0

    def __post_init__(self):
        floor = self.floor
        if isinstance(floor, bool) or not isinstance(floor, float | int) or not 0 <= floor <= 1:
            raise ValueError(f"Cosine(floor={self.floor!r}) is not allowed; expected a fraction in [0, 1] of "
                             "the lr at the last step")

    def __call__(self, step: int, steps: int) -> float:
        t = min(step, steps) / max(steps, 1)
        return self.floor + (1 - self.floor) * 0.5 * (1 + math.cos(math.pi * t))
