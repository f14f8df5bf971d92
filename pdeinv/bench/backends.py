"""One line per backend of a scene's operator: build time, apply time, memory, agreement.

Every kind applies the same discrete map: time stepping, a dense matrix, a truncated SVD and the
scene's own kind (e.g. modal). A line: the one-off ``build_s``, ``apply_s`` (best forward of a
batch), ``memory_mb`` (the backend's arrays), ``agreement`` (relative difference from stepping on
random fields) and, for spectral bases, the ``rank``; a kind over its memory budget is ``refused``.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import TooManyModes
from ..physics.capabilities import modal_basis
from .timing import best, compiled, stepping


def _memory_mb(backend) -> float:
    arrays = [v for v in vars(backend).values() if isinstance(v, np.ndarray)] if backend is not None else []
    return sum(a.nbytes for a in arrays) / 2**20


def lines(problem, batch: int = 16, repeats: int = 3, seed: int = 0) -> dict:
    """``{name: line}`` for stepping, dense and SVD (and the scene's own kind if another one)."""
    op = problem.operator
    run = stepping(op)
    if run is None:
        return {"skipped": f"{op!r} does not step through time"}
    X = np.random.default_rng(seed).standard_normal((batch, op.n_in))
    ref = run.forward(X)
    out = {}
    for kind in ("steps", "dense", "svd"):
        t = time.perf_counter()
        try:
            cand = compiled(op, kind, problem.disc.M)
        except (TooManyModes, ValueError) as err:
            out[kind] = {"outcome": "refused", "message": str(err)}
            continue
        out[kind] = {"build_s": time.perf_counter() - t, "op": cand}
    out.setdefault(op.kind, {"build_s": None, "op": op})  # e.g. the modal heat basis
    for line in out.values():
        if "op" not in line:
            continue
        cand = line.pop("op")
        basis = modal_basis(cand)
        diff = np.linalg.norm(cand.forward(X) - ref) / np.linalg.norm(ref)
        line.update(apply_s=best(lambda c=cand: c.forward(X), repeats), memory_mb=_memory_mb(cand.backend),
                    outcome="ok", agreement=float(diff), rank=None if basis is None else basis.k)
    return {"scene_choice": op.choice, "batch": batch, "lines": out}
