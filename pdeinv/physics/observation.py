"""What a time-stepping run records: the final field, or sensor records every ``k`` steps.

With ``n = steps``, ``k = every`` and ``R = n/k`` records, record ``r`` is taken
after step ``j = (r+1)k`` (not at ``t = 0``) through the observation matrix ``S``
(``n_s × N``; the identity when ``S`` is None):

    y_r = S u_{(r+1)k},      r = 0, …, R−1.

**Layout of y (record-major):** ``y[b, r·n_s + s]`` is sensor ``s`` at time
``t_r = (r+1)·k·dt``; ``y.reshape(B, R, n_s)`` gives the time series. ``every``
must divide ``steps`` so the records are uniform in time and the last one is the
final field.

The *output space* is declared, never guessed from shapes: :class:`FinalField`
observes a field on the mesh (``space = "field"``, measured with the mass ``M``);
:class:`Records` plain numbers (``space = "records"``, Euclidean), whatever their count.
"""

from __future__ import annotations

import numpy as np

from .._checks import count


def _records(steps: int, every) -> int:
    k = count(every, "record_every")
    if steps % k:
        divisors = [d for d in range(1, steps + 1) if steps % d == 0]
        shown = ", ".join(map(str, divisors[:12])) + (", …" if len(divisors) > 12 else "")
        raise ValueError(
            f"record_every={every!r} does not divide steps={steps}; allowed: a divisor of "
            f"steps ({shown}), so that records are uniform in time and include the final field"
        )
    return steps // k


class Records:
    """``S u`` after every ``every``-th of ``steps`` steps (module docstring)."""

    space = "records"

    def __init__(self, S, n: int, steps: int, every: int = 1):
        if S is not None:
            if S.shape[1] != n:
                raise ValueError(f"sensor matrix has shape {S.shape}; expected (n_sensors, {n})")
            if S.shape[0] == 0:
                raise ValueError("the sensor matrix has no rows; expected at least one sensor")
            S = S.tocsr()
        self.S, self.ST = S, None if S is None else S.T.tocsr()
        self.every = int(every)
        self.n_records = _records(steps, every)
        self.n_sensors = n if S is None else S.shape[0]
        self.n_out = self.n_sensors * self.n_records

    def times(self, dt: float) -> np.ndarray:
        """Time of each record, ``(r+1)·k·dt``."""
        return (np.arange(self.n_records) + 1) * self.every * dt

    def _slot(self, j: int):
        r = j // self.every - 1
        return slice(r * self.n_sensors, (r + 1) * self.n_sensors)

    def write(self, Y: np.ndarray, j: int, U: np.ndarray) -> None:
        """Store ``S U`` into ``Y`` if step ``j`` (1-based) is recorded."""
        if j % self.every == 0:
            Y[:, self._slot(j)] = (U if self.S is None else self.S @ U).T

    def read_T(self, R: np.ndarray, j: int):
        """``Sᵀ r_j`` as ``(N, B)`` if step ``j`` is recorded, else ``None`` (transposes :meth:`write`)."""
        if j % self.every:
            return None
        Rj = R[:, self._slot(j)].T
        return Rj if self.ST is None else self.ST @ Rj


class FinalField(Records):
    """The field after the last step: ``y = u_n`` (one record, no sensor matrix)."""

    space = "field"

    def __init__(self, n: int, steps: int):
        super().__init__(None, n, steps, every=steps)
