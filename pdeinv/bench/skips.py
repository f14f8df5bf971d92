""""Skip what a scene doesn't need", each skip measured against the work it avoids.

* ``modal``: the truncated modal form instead of time stepping (dead modes skipped);
* ``no_trajectory``: the adjoint of a linear scheme needs no stored trajectory (the baseline
  stores every step's state, as a generic nonlinear adjoint must);
* ``no_adjoint_under_no_grad``: ``pdeinv.apply`` under ``torch.no_grad`` runs no adjoint;
* ``factorization_reuse``: one factorization for all steps and batch columns (the baseline
  refactorizes ``A`` every step);
* ``hig_jacobian_only_for_hig``: GD and SIP never build ``∂y/∂θ``; its size is what they save.

Each entry: the cost with and without the skip and ``saved``, the factor gained, from one run.
"""

from __future__ import annotations

import numpy as np
import torch

from ..physics.base import LinearOperator
from ..physics.bridge import apply
from .timing import best, peak_bytes, stepping


class Counting(LinearOperator):
    """``op``, counting its adjoint calls."""

    def __init__(self, op):
        self.op, self.n_in, self.n_out, self.adjoints = op, op.n_in, op.n_out, 0

    def _forward(self, X):
        return self.op.forward(X)

    def _adjoint(self, R):
        self.adjoints += 1
        return self.op.adjoint(R)


def trajectory(op, X, R) -> dict:
    """Peak traced memory of our adjoint vs a forward that stores every step's state."""
    run = stepping(op)
    if run is None:
        return {"skipped": "no time-stepping operator"}
    sc = run.scheme

    def stored():  # np.array copies: solver outputs may live in torch memory tracemalloc cannot see
        traj = [sc.start(X.T.copy())]
        for _ in range(run.steps):
            traj.append(tuple(np.array(a) for a in sc.step(traj[-1])))
        return traj

    ours = peak_bytes(lambda: np.array(run.adjoint(R)))
    base = peak_bytes(stored)
    return {"adjoint_peak_bytes": ours, "stored_trajectory_peak_bytes": base, "saved": base / max(ours, 1),
            "note": "tracemalloc sees numpy memory only (not the solver's own)"}


def no_grad(op, X, repeats) -> dict:
    """Forward under ``no_grad`` (adjoint never runs) vs forward + backward."""
    counting = Counting(op)
    x = torch.as_tensor(X, dtype=torch.float64).requires_grad_(True)

    def plain():
        with torch.no_grad():
            apply(counting, x)

    def both():
        apply(counting, x).sum().backward()

    plain()
    adj_after_no_grad = counting.adjoints
    t_plain, t_both = best(plain, repeats), best(both, repeats)
    return {"adjoint_calls_under_no_grad": adj_after_no_grad, "no_grad_s": t_plain,
            "with_backward_s": t_both, "saved": t_both / t_plain}


def factorization(op, X, repeats) -> dict:
    """The stepping forward vs it plus ``steps`` factorizations of ``A`` by the same solver type."""
    run = stepping(op)
    lu = None if run is None else run.scheme.lu  # explicit schemes declare None
    if lu is None:
        return {"skipped": "no implicit time-stepping operator"}
    t_ours = best(lambda: run.forward(X), repeats)
    t_factor = best(lambda: type(lu)(run.scheme.A), repeats)
    t_base = t_ours + run.steps * t_factor
    return {"reused_s": t_ours, "refactorized_s": t_base, "factorization_s": t_factor,
            "saved": t_base / t_ours}


def measure(problem, steps_info: dict | None = None, batch: int = 16, repeats: int = 3, seed: int = 0,
            modal_info: dict | None = None) -> dict:
    """All skip measurements for ``problem``; ``steps_info``/``modal_info`` come from the ratio probes."""
    op, rng = problem.operator, np.random.default_rng(seed)
    X, R = rng.standard_normal((batch, op.n_in)), rng.standard_normal((batch, op.n_out))
    out = {"no_trajectory": trajectory(op, X, R), "no_adjoint_under_no_grad": no_grad(op, X, repeats),
           "factorization_reuse": factorization(op, X, repeats)}
    m = modal_info or {}
    out["modal"] = ({"modes_kept": m.get("modal_modes"), "N": op.n_in, "saved": m["modal_speedup"],
                     "agreement": m.get("modal_agreement")} if m.get("modal_speedup") is not None
                    else {"skipped": m.get("modal_refused", "no modal form measured")})
    if steps_info:
        rows, params = steps_info["hig_jacobian"]
        out["hig_jacobian_only_for_hig"] = {
            "jacobian_mb_avoided_by_gd_sip": steps_info["hig_jacobian_mb"], "jacobian_shape": [rows, params],
            "hig_step_s": steps_info["hig_step_s"], "gd_step_s_same_net": steps_info["gd_step_s"],
            "saved": steps_info["hig_step_s"] / steps_info["gd_step_s"]}
    return out
