"""A time budget that means the same work on an idle and on a loaded machine.

``Budget(seconds)`` counts the CPU seconds of the calling thread (``time.thread_time``): with one torch
and one BLAS thread (``--threads 1``) all the work runs there, so the budget buys the same steps whatever
else the machine runs (on an idle machine it equals the wall time). Wall seconds are capped at
``wall_factor`` times the budget, so that a machine several times oversubscribed, or work the thread only
waits for (a GPU's kernels, other BLAS threads), still ends. Measured before: the prior fit's 300 wall
seconds bought 37 417 steps on a 2-core machine running two jobs and 23 762 running five (sine_gordon_1d
x_err 0.0558 against 0.0604 for the same linear part).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

#: wall seconds allowed per budgeted second (:class:`Budget`)
WALL_FACTOR = 3.0


@dataclass
class Budget:
    seconds: float | None  # None: no limit
    wall_factor: float = WALL_FACTOR
    _cpu0: float = field(default_factory=time.thread_time, repr=False)
    _wall0: float = field(default_factory=time.perf_counter, repr=False)

    def spent(self) -> float:
        """CPU seconds of this thread since the start."""
        return time.thread_time() - self._cpu0

    def wall(self) -> float:
        return time.perf_counter() - self._wall0

    def over(self, ahead: float = 1.0) -> bool:
        """Whether ``ahead`` times what is spent so far exceeds the budget (``ahead > 1``: whether the
        next chunk of the same size would), on the thread's CPU clock or the capped wall clock."""
        if self.seconds is None:
            return False
        return ahead * self.spent() > self.seconds or ahead * self.wall() > self.wall_factor * self.seconds
