"""Cost ratios measured in one run (the machine is shared and noisy: ratios, not absolute times).

Each timing is the minimum over ``repeats`` rounds, the functions compared run one
after the other within each round (interleaved), so a burst of load from other
processes hits all of them alike; the minimum filters interference better than the mean.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as sla

from .timing import interleaved


def operator_ratios(problem, batch: int = 64, repeats: int = 5, seed: int = 0) -> dict:
    """Forward/adjoint costs of a problem's operator against bare scipy baselines.

    * ``forward_vs_splu``: our batched time-stepping forward (default solver) / a
      bare loop ``U ← lu.solve(B @ U)`` with ``scipy.sparse.linalg.splu`` (default
      options) on the same matrices and batch (wave: the same Newmark update,
      ``U' = lu.solve(B U + dt M V)``, ``V' = 2(U' − U)/dt − V``);
    * ``overhead_vs_bare``: the same with *our* stepping forced onto the bare
      loop's own SuperLU object: the pure overhead of the operator layer;
    * ``adjoint_vs_forward``: adjoint / forward time of the same operator;
    * ``modal_speedup`` (heat only): time-stepping forward / modal forward, with
      ``modal_agreement`` the relative difference of their results.
    """
    from ..physics import Heat
    from ..physics.capabilities import modal_basis
    from ..physics.schemes import Newmark, Theta
    from .timing import stepping

    op = problem.operator
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((batch, op.n_in))
    R = rng.standard_normal((batch, op.n_out))
    out = {"batch": batch, "N": op.n_in}
    steps = stepping(op)
    if steps is None or not isinstance(steps.scheme, (Theta, Newmark)):
        t = interleaved({"fwd": lambda: op.forward(X), "adj": lambda: op.adjoint(R)}, repeats)
        return {**out, "forward_s": t["fwd"], "adjoint_vs_forward": t["adj"] / t["fwd"]}
    sc = steps.scheme
    lu = sla.splu(sc.A.tocsc())

    def bare_theta():
        U = X.T.copy()
        for _ in range(steps.steps):
            U = lu.solve(sc.B @ U)
        return U

    def bare_newmark():  # the same Newmark step as schemes.Newmark.step, written with scipy only
        U, V, dt = X.T.copy(), np.zeros_like(X.T), sc.dt
        for _ in range(steps.steps):
            U1 = lu.solve(sc.B @ U + dt * (sc.M @ V))
            U, V = U1, (2.0 / dt) * (U1 - U) - V
        return U

    fns = {"bare": bare_newmark if isinstance(sc, Newmark) else bare_theta,
           "fwd": lambda: steps.forward(X), "adj": lambda: steps.adjoint(R)}
    if isinstance(sc, Theta):  # our loop on the bare loop's own SuperLU object: the layer's overhead
        same = Heat(op.M, op.K, op.kappa, op.t_end, op.steps, op.scheme, backend="steps",
                    solver=lambda _: lu, C=op.C)
        fns["same"] = lambda: same.forward(X)
    modal = modal_basis(op)
    if modal is None and isinstance(sc, Theta) and op.symmetric:
        try:
            modal = Heat(op.M, op.K, op.kappa, op.t_end, op.steps, op.scheme, backend="modal").modes
        except ValueError:
            modal = None
    if modal is not None:
        fns["modal"] = lambda: modal.forward(X)
    t = interleaved(fns, repeats)
    out.update(forward_s=t["fwd"], forward_vs_splu=t["fwd"] / t["bare"],
               adjoint_vs_forward=t["adj"] / t["fwd"], solver=type(sc.lu).__name__)
    if "same" in t:
        out["overhead_vs_bare"] = t["same"] / t["bare"]
    if "modal" in t:
        ys = steps.forward(X)
        out.update(modal_speedup=t["fwd"] / t["modal"], modal_modes=modal.k,
                   modal_agreement=float(np.linalg.norm(modal.forward(X) - ys) / np.linalg.norm(ys)))
    return out
