"""Wave local inverses by running Newmark backwards (exact time reversibility).

Newmark average acceleration is the trapezoidal rule on ``(u, v)``; the same step
with ``−dt`` undoes it exactly, so ``reverse(final_state(u₀, v₀)) = (u₀, v₀)`` to
rounding. Write the reversed run as ``(u₀, v₀) = R_u u_T + R_v v_T``.

:class:`TimeReversal` (observation ``y = u_T`` only). The velocity is not
observed, so borrow it from the forward run of the current guess:
``P⁻¹_(x₀, y₀)(y) = first component of reverse(y, v_T(x₀))``. Linearity gives,
for ``y = P(x₀ + εd)``,

    P⁻¹(y) − (x₀ + εd) = −ε (R_v v_T(d))_u,

so it is exact at ``y = y₀`` and its error is *exactly linear* in the step
``ε`` — a first-order-accurate local inverse (Holl et al. 2022, §4): the
neglected term is the velocity change the displacement change would have
caused. Cost: two Newmark runs (forward for ``v_T(x₀)``, then back), i.e.
2 forward units, with no α and no iteration.

:class:`StateReversal` (observation ``y = [u_T, v_T]``): the exact inverse.

When to prefer time reversal over the regularized solve (:class:`.TikhonovCG`):
for the wave operator, which conserves energy, nothing is damped, so the
inverse of the full state is perfectly conditioned and reversal costs one run
instead of the dozens of forward+adjoint pairs CG needs; it introduces no α
bias. Prefer the regularized solve when the map really loses information
(diffusion, sensors observing part of the field) — reversing a dissipative
scheme amplifies every damped mode — or when the missing velocity is large
compared with the steps SIP takes (its error is first order in the step).
"""

from __future__ import annotations

import numpy as np

from .._checks import batch
from ..physics.capabilities import reversible
from ._inputs import out, pair


class TimeReversal:
    """``P⁻¹_(x₀, Px₀)(y) = u-part of Wave.reverse(y, v_T(x₀))`` for a :class:`~pdeinv.physics.Wave`."""

    def __init__(self, op):
        if not reversible(op):
            raise ValueError(f"TimeReversal needs a time-reversible operator (declared by its scheme: "
                             f"Newmark or leapfrog, final field observed); got {op!r}")
        self.op = op

    def __call__(self, y, x0) -> np.ndarray:
        Y, X0, single = pair(y, x0, self.op.n_out, self.op.n_in)
        _, VT = self.op.final_state(X0)
        U0, _ = self.op.reverse(Y, VT)
        return out(U0, single)

    def __repr__(self):
        return f"TimeReversal({self.op!r})"


class StateReversal:
    """Exact inverse of the full final state: ``y = [u_T, v_T]`` (shape ``(B, 2N)``) → ``u₀``.

    ``x0`` is not needed (pass ``None``) but, if given, must have the right shape.
    """

    def __init__(self, op):
        TimeReversal(op)  # same requirements
        self.op = op

    def __call__(self, y, x0=None) -> np.ndarray:
        N = self.op.n_in
        Y, single = batch(y, 2 * N, "y")
        if x0 is not None:
            pair(Y[:, :N], x0, N, N)
        U0, _ = self.op.reverse(Y[:, :N], Y[:, N:])
        return out(U0, single)

    def __repr__(self):
        return f"StateReversal({self.op!r})"
