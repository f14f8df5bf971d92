"""One line per backend of a scene's operator: build time, apply time, memory, agreement.

Every backend applies the same discrete map (:mod:`pdeinv.physics.compiled`): time stepping,
the modal basis (heat), a dense matrix, a truncated SVD. Each line holds the one-off
``build_s``, ``apply_s`` (best forward time on a batch), ``memory_mb`` (the arrays the
backend keeps), ``agreement`` (relative difference from stepping on random fields) and,
for spectral bases, the ``rank`` kept; a backend over its memory budget is ``refused``.
"""

from __future__ import annotations

import time

import numpy as np

from ..physics import Propagator
from .timing import best, stepping


def _memory_mb(backend) -> float:
    arrays = [v for v in vars(backend).values() if isinstance(v, np.ndarray)] if backend is not None else []
    return sum(a.nbytes for a in arrays) / 2**20


def lines(problem, batch: int = 16, repeats: int = 3, seed: int = 0) -> dict:
    """``{name: line}`` for stepping, dense and SVD (and the scene's own backend if different)."""
    op = problem.operator
    run = stepping(op)
    if run is None:
        return {"skipped": f"{type(op).__name__} is not a time-stepping operator"}
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((batch, op.n_in))
    ref = run.forward(X)
    out = {}
    for kind in ("steps", "dense", "svd"):
        t = time.perf_counter()
        try:
            cand = Propagator(run.scheme, run.observation, run.steps, run.mass).compile(kind, problem.disc.M)
        except ValueError as err:
            out[kind] = {"outcome": "refused", "message": str(err)}
            continue
        out[kind] = {"build_s": time.perf_counter() - t, "backend": cand.backend}
    backend = getattr(op, "backend", None)  # None: the scene steps through time itself (backend=steps)
    if backend is not None and backend.name not in out:  # e.g. the modal heat basis
        out[backend.name] = {"build_s": None, "backend": backend}
    for line in out.values():
        if "backend" not in line:
            continue
        b = line.pop("backend")
        fwd = run.forward if b is None else b.forward
        line.update(apply_s=best(lambda f=fwd: f(X), repeats), memory_mb=_memory_mb(b), outcome="ok",
                    agreement=float(np.linalg.norm(fwd(X) - ref) / np.linalg.norm(ref)),
                    rank=len(b.g) if hasattr(b, "g") else None)
    return {"scene_choice": getattr(op, "choice", None), "batch": batch, "lines": out}
