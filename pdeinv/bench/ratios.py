"""Cost ratios measured in one run (the machine is shared and noisy: ratios, not absolute times).

Each timing is the minimum over ``repeats`` interleaved runs, which filters out
interference from other processes better than the mean.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as sla

from .timing import best as _best


def operator_ratios(problem, batch: int = 64, repeats: int = 5, seed: int = 0) -> dict:
    """Forward/adjoint costs of a problem's operator against bare scipy baselines.

    * ``forward_vs_splu``: our batched time-stepping forward (default solver) / a
      bare loop ``U ← lu.solve(B @ U)`` with ``scipy.sparse.linalg.splu`` (default
      options) on the same matrices and batch;
    * ``overhead_vs_bare``: the same with *our* stepping forced onto the bare
      loop's own SuperLU object: the pure overhead of the operator layer;
    * ``adjoint_vs_forward``: adjoint / forward time of the same operator;
    * ``modal_speedup`` (heat only): time-stepping forward / modal forward, with
      ``modal_agreement`` the relative difference of their results.
    """
    from ..physics import Heat

    op = problem.operator
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((batch, op.n_in))
    R = rng.standard_normal((batch, op.n_out))
    out = {"batch": batch, "N": op.n_in}
    if isinstance(op, Heat):
        steps = op if op.backend.name == "steps" else Heat(
            op.M, op.K, op.kappa, op.t_end, op.steps, op.scheme, backend="steps")
        A, B = steps.backend.A, steps.backend.B
    else:
        steps, A, B = op, op.A, op.B
    lu = sla.splu(A.tocsc())

    def bare():
        U = X.T.copy()
        for _ in range(steps.steps):
            U = lu.solve(B @ U)
        return U

    if isinstance(op, Heat):  # the wave step has a second matvec: compare heat only
        t_bare = _best(bare, repeats)
        t_fwd = _best(lambda: steps.forward(X), repeats)
        out["forward_vs_splu"] = t_fwd / t_bare
        same = Heat(op.M, op.K, op.kappa, op.t_end, op.steps, op.scheme, backend="steps",
                    solver=lambda _: lu)
        out["overhead_vs_bare"] = _best(lambda: same.forward(X), repeats) / t_bare
        out["solver"] = type(steps.backend.lu).__name__
    t_fwd = _best(lambda: steps.forward(X), repeats)
    t_adj = _best(lambda: steps.adjoint(R), repeats)
    out.update(forward_s=t_fwd, adjoint_vs_forward=t_adj / t_fwd)
    if isinstance(op, Heat):
        modal = op if op.backend.name == "modal" else None
        if modal is None:
            try:
                modal = Heat(op.M, op.K, op.kappa, op.t_end, op.steps, op.scheme, backend="modal")
            except ValueError:
                return out
        t_modal = _best(lambda: modal.forward(X), repeats)
        ys = steps.forward(X)
        out.update(
            modal_speedup=t_fwd / t_modal,
            modal_modes=modal.backend.k,
            modal_agreement=float(np.linalg.norm(modal.forward(X) - ys) / np.linalg.norm(ys)),
        )
    return out
