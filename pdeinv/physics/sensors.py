"""Sensor time series of the heat and wave fields, with exact discrete adjoints.

With ``n = steps`` time steps, ``k = record_every`` and ``R = n/k`` records, the
forward map observes the field after steps ``k, 2k, …, n`` (not at ``t = 0``)
through the sensor matrix ``S`` (``n_s × N``, :func:`pdeinv.observe.sensor_matrix`):

    y_r = S u_{(r+1)k},      r = 0, …, R−1.

**Layout of y (record-major):** ``y[b, r·n_s + s]`` is sensor ``s`` at time
``t_r = (r+1)·k·dt``; ``y.reshape(B, R, n_s)`` gives the time series.
``record_every`` must divide ``steps`` so the records are uniform in time and
the last one is the final field; anything else raises ``ValueError``.

Adjoint (the exact transpose of the discrete map, no stored trajectory): a
reverse sweep over the steps that injects ``Sᵀ r_r`` into the adjoint state just
before transposing the step that produced record ``r``,

    heat:  w ← 0;  for j = n…1:  w += Sᵀ r_j (if j is recorded);  w ← B A⁻¹ w,

and likewise for Newmark with the transposed state step of :mod:`.wave`.
Cost: forward and adjoint are one run each (``n`` solves on all batch columns),
plus a sparse ``S`` product per record.
"""

from __future__ import annotations

import numpy as np

from .._checks import count
from .base import LinearOperator
from .heat_backends import Stepping


def _records(steps: int, record_every) -> int:
    k = count(record_every, "record_every")
    if steps % k:
        divisors = [d for d in range(1, steps + 1) if steps % d == 0]
        shown = ", ".join(map(str, divisors[:12])) + (", …" if len(divisors) > 12 else "")
        raise ValueError(
            f"record_every={record_every!r} does not divide steps={steps}; allowed: a divisor of "
            f"steps ({shown}), so that records are uniform in time and include the final field"
        )
    return steps // k


class _Sensors(LinearOperator):
    """Shared bookkeeping: ``S``, the record schedule, and the y layout."""

    def __init__(self, S, steps: int, record_every: int, n_in: int):
        if S.shape[1] != n_in:
            raise ValueError(f"sensor matrix has shape {S.shape}; expected (n_sensors, {n_in})")
        if S.shape[0] == 0:
            raise ValueError("the sensor matrix has no rows; expected at least one sensor")
        self.S = S.tocsr()
        self.ST = self.S.T.tocsr()
        self.record_every = int(record_every)
        self.n_records = _records(steps, record_every)
        self.n_sensors = S.shape[0]
        self.n_in = n_in
        self.n_out = self.n_sensors * self.n_records

    def times(self, dt: float) -> np.ndarray:
        """Time of each record, ``(r+1)·k·dt``."""
        return (np.arange(self.n_records) + 1) * self.record_every * dt

    def _record(self, Y, j, U):
        """Store ``S U`` as record of step ``j`` (1-based) if ``j`` is recorded."""
        if j % self.record_every == 0:
            r = j // self.record_every - 1
            Y[:, r * self.n_sensors:(r + 1) * self.n_sensors] = (self.S @ U).T

    def _inject(self, R, j, W):
        """``W + Sᵀ r_j`` if step ``j`` is recorded (the transpose of :meth:`_record`)."""
        if j % self.record_every == 0:
            r = j // self.record_every - 1
            return W + self.ST @ R[:, r * self.n_sensors:(r + 1) * self.n_sensors].T
        return W


class HeatSensors(_Sensors):
    """Sensor time series of the θ-scheme heat run of ``heat`` (a :class:`~pdeinv.Heat`).

    Always time-steps: reuses ``heat.backend`` when it is a :class:`Stepping`,
    otherwise builds one (same ``A``, ``B``, solver). forward: ``u ← A⁻¹(B u)``,
    record ``S u`` every ``record_every`` steps; adjoint: module docstring.
    """

    def __init__(self, heat, S, record_every: int = 1):
        super().__init__(S, heat.steps, record_every, heat.n_in)
        self.heat = heat
        self.stepping = heat.backend if isinstance(heat.backend, Stepping) else Stepping(heat)
        self.steps, self.dt = heat.steps, heat.dt

    def _forward(self, X):
        st = self.stepping
        Y = np.empty((X.shape[0], self.n_out))
        U = X.T
        for j in range(1, self.steps + 1):
            U = st.lu.solve(st.B @ U)
            self._record(Y, j, U)
        return Y

    def _adjoint(self, R):
        st = self.stepping
        W = np.zeros((self.n_in, R.shape[0]))
        for j in range(self.steps, 0, -1):
            W = st.B @ st.lu.solve(self._inject(R, j, W))
        return np.ascontiguousarray(W.T)

    def __repr__(self):
        return (f"HeatSensors(N={self.n_in}, sensors={self.n_sensors}, records={self.n_records}, "
                f"record_every={self.record_every}, {self.heat!r})")


class WaveSensors(_Sensors):
    """Sensor time series of the Newmark run of ``wave`` (a :class:`~pdeinv.Wave`), ``v₀ = 0``.

    forward: ``(u, v) ← step(u, v)``, record ``S u``; adjoint: with
    ``s = 2/dt``, ``(ū, v̄) ← 0`` and for ``j = n…1``: ``ū += Sᵀ r_j`` (if recorded),
    ``w = A⁻¹(ū + s v̄)``, ``(ū, v̄) ← (B w − s v̄, dt M w − v̄)``; the result is ``ū``.
    """

    def __init__(self, wave, S, record_every: int = 1):
        super().__init__(S, wave.steps, record_every, wave.n_in)
        self.wave = wave
        self.steps, self.dt = wave.steps, wave.dt

    def _forward(self, X):
        Y = np.empty((X.shape[0], self.n_out))
        U, V = X.T, np.zeros_like(X.T)
        for j in range(1, self.steps + 1):
            U, V = self.wave._step(U, V, self.dt)
            self._record(Y, j, U)
        return Y

    def _adjoint(self, R):
        w, s = self.wave, 2.0 / self.dt
        Ub = np.zeros((self.n_in, R.shape[0]))
        Vb = np.zeros_like(Ub)
        for j in range(self.steps, 0, -1):
            Ub = self._inject(R, j, Ub)
            W = w.lu.solve(Ub + s * Vb)
            Ub, Vb = w.B @ W - s * Vb, self.dt * (w.M @ W) - Vb
        return np.ascontiguousarray(Ub.T)

    def __repr__(self):
        return (f"WaveSensors(N={self.n_in}, sensors={self.n_sensors}, records={self.n_records}, "
                f"record_every={self.record_every}, {self.wave!r})")
