"""Cost ratios measured in one run (the machine is shared and noisy: ratios, not absolute times).

Each timing is the minimum over ``repeats`` rounds, the functions compared run one
after the other within each round (interleaved), so a burst of load from other
processes hits all of them alike; the minimum filters interference better than the mean.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as sla

from ..errors import TooManyModes
from ..physics.capabilities import modal_basis
from .timing import compiled, interleaved, stepping


def operator_ratios(problem, batch: int = 64, repeats: int = 5, seed: int = 0) -> dict:
    """Forward/adjoint costs of a problem's operator applied by time stepping (``op.stepping()``).

    * ``forward_vs_splu`` (implicit schemes): our forward / a bare scipy loop of as many steps, each
      one product with the scheme's ``B`` and one ``splu`` solve with its ``A`` (default options,
      same batch): the whole θ-step; Newmark's step adds a product with ``M`` and the velocity update;
    * ``overhead_vs_bare``: our forward / the scheme's own ``start``, ``step`` and ``field`` in a plain
      loop (the same solver object): the cost of the operator layer;
    * ``adjoint_vs_forward``: adjoint / forward time;
    * ``modal_speedup`` where the modal form is offered (a symmetric θ-scheme, final field): time
      stepping / modal forward, with ``modal_agreement`` their relative difference; else
      ``modal_refused``, why not.
    """
    op = problem.operator
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((batch, op.n_in))
    R = rng.standard_normal((batch, op.n_out))
    out = {"batch": batch, "N": op.n_in}
    run = stepping(op)
    if run is None:
        t = interleaved({"fwd": lambda: op.forward(X), "adj": lambda: op.adjoint(R)}, repeats)
        return {**out, "forward_s": t["fwd"], "adjoint_vs_forward": t["adj"] / t["fwd"]}
    sc = run.scheme

    def own():  # the scheme's step in a plain loop
        s = sc.start(X.T)
        for _ in range(run.steps):
            s = sc.step(s)
        return sc.field(s)

    fns = {"fwd": lambda: run.forward(X), "adj": lambda: run.adjoint(R), "own": own}
    lu = getattr(sc, "lu", None)  # an implicit scheme: a factorized A
    if lu is not None:
        bare_lu = sla.splu(sc.A.tocsc())

        def bare():
            U = X.T.copy()
            for _ in range(run.steps):
                U = bare_lu.solve(sc.B @ U)
            return U

        fns["bare"] = bare
    try:
        modal = modal_basis(op) or modal_basis(compiled(op, "modal"))
        fns["modal"] = lambda: modal.forward(X)
    except (TooManyModes, ValueError) as err:
        out["modal_refused"] = str(err)
    t = interleaved(fns, repeats)
    out.update(forward_s=t["fwd"], adjoint_vs_forward=t["adj"] / t["fwd"],
               overhead_vs_bare=t["fwd"] / t["own"])
    if lu is not None:
        out.update(forward_vs_splu=t["fwd"] / t["bare"], solver=type(lu).__name__)
    if "modal" in t:
        ys = run.forward(X)
        out.update(modal_speedup=t["fwd"] / t["modal"], modal_modes=modal.k,
                   modal_agreement=float(np.linalg.norm(modal.forward(X) - ys) / np.linalg.norm(ys)))
    return out
