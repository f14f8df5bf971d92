"""Timing, memory and machine facts shared by the benchmarks, and the operator accessors they use.

Times are minima over repeats: interference from other processes on a shared machine only ever
adds time, so the minimum estimates the undisturbed cost better than the mean."""

from __future__ import annotations

import copy
import os
import platform
import time
import tracemalloc

import numpy as np


def best(fn, repeats: int = 3) -> float:
    """Minimum wall time of ``fn()`` over ``repeats`` runs after one warm-up, in seconds."""
    return interleaved({"fn": fn}, repeats)["fn"]


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
    """``op`` applied by time stepping (:meth:`pdeinv.physics.Propagator.stepping`), or ``None`` for an
    operator that does not step through time (a :class:`~pdeinv.physics.Matrix`, a user's own)."""
    return op.stepping()  # declared: None for an operator with no time-stepping form


def compiled(op, kind: str, M=None):
    """A copy of the time-stepping ``op`` applied by ``kind`` (``ValueError`` or ``TooManyModes`` where
    refused), sharing its scheme and factorization: :meth:`~pdeinv.physics.Propagator.compile` changes
    the operator it is called on, and the scene's operator keeps its backend."""
    if stepping(op) is None:
        raise ValueError(f"{op!r} does not step through time: it has no backends")
    return copy.copy(op).compile(kind, M)
