"""Timing, memory and machine facts shared by the benchmarks (the machine is shared and noisy).

``best`` takes the minimum over repeats: interference from other processes only ever
adds time, so the minimum estimates the undisturbed cost better than the mean.
"""

from __future__ import annotations

import os
import platform
import time
import tracemalloc

import numpy as np


def best(fn, repeats: int = 3) -> float:
    """Minimum wall time of ``fn()`` over ``repeats`` runs, in seconds."""
    out = np.inf
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        fn()
        out = min(out, time.perf_counter() - t)
    return out


def interleaved(fns: dict, repeats: int = 3) -> dict:
    """``{name: minimum time}`` with the functions run round-robin, ``repeats`` rounds (after one warm-up)."""
    for fn in fns.values():
        fn()
    out = dict.fromkeys(fns, np.inf)
    for _ in range(max(1, repeats)):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            out[name] = min(out[name], time.perf_counter() - t)
    return out


def peak_bytes(fn) -> int:
    """Peak of the memory traced by ``tracemalloc`` while ``fn()`` runs (numpy arrays are traced)."""
    was = tracemalloc.is_tracing()
    if not was:
        tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    fn()
    peak = tracemalloc.get_traced_memory()[1] - base
    if not was:
        tracemalloc.stop()
    return int(peak)


def machine() -> dict:
    """Cores, library versions and platform, stored with every benchmark."""
    import scipy
    import torch

    return {"cores": os.cpu_count(), "torch_threads": torch.get_num_threads(),
            "torch": torch.__version__, "scipy": scipy.__version__, "numpy": np.__version__,
            "python": platform.python_version(), "platform": platform.platform(),
            "load_avg_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None}


def stepping(op):
    """``op`` as a time-stepping :class:`~pdeinv.physics.Propagator` (``scheme`` public), or ``None``:
    a stepping propagator as is, a compiled one (its ``backend`` a dense or SVD map) rebuilt without
    the backend — the bench once timed the dense map as "steps" and compared it with itself — and an
    operator with a ``stepper`` (:attr:`pdeinv.Heat.stepper`) its final-field run."""
    from ..physics import FinalField, Propagator

    if isinstance(op, Propagator):  # a compiled one (dense, SVD) rebuilt uncompiled: its time stepping
        return op if getattr(op, "backend", None) is None else \
            Propagator(op.scheme, op.observation, op.steps, op.mass)
    if getattr(op, "stepper", None) is None:
        return None
    return Propagator(op.stepper, FinalField(op.n_in, op.steps), op.steps, getattr(op, "mass", None))
