"""Cost ratios measured in one run: :func:`operator_ratios` of the physics, :func:`step_ratios` of a step.

The functions compared run one after the other in each of ``repeats`` rounds (interleaved), so a
burst of load from other processes hits all of them alike; each time is the minimum over rounds."""

from __future__ import annotations

import copy

import numpy as np
import scipy.sparse.linalg as sla
import torch

from ..errors import TooManyModes
from ..methods.presets import make_rule
from ..nets import fit_preconditioning
from ..physics.capabilities import modal_basis
from ..physics.nonlinear import is_linear
from .timing import compiled, interleaved, stepping


def operator_ratios(problem, batch: int = 64, repeats: int = 5, seed: int = 0) -> dict:
    """Forward/adjoint costs of a problem's operator applied by time stepping (``op.stepping()``).

    * ``forward_vs_splu`` (implicit schemes): our forward / a bare scipy loop of as many steps of
      one product with the scheme's ``B`` and one ``splu`` solve with its ``A`` (the whole θ-step;
      Newmark's adds a product with ``M`` and the velocity update);
    * ``overhead_vs_bare``: our forward / the scheme's ``start``, ``step``, ``field`` in a plain loop;
    * ``adjoint_vs_forward``; ``modal_speedup`` where the modal form is offered: stepping / modal
      forward, ``modal_agreement`` their relative difference (else ``modal_refused``: why not).
    """
    op, rng = problem.operator, np.random.default_rng(seed)
    X, R = rng.standard_normal((batch, op.n_in)), rng.standard_normal((batch, op.n_out))
    stepped = stepping(op)
    out, run = {"batch": batch, "N": op.n_in}, op if stepped is None else stepped
    # nonlinear physics: its adjoint is the vector–Jacobian product at the forward's inputs
    adjoint = (lambda: run.adjoint(R)) if is_linear(op) else (lambda: run.vjp(X, R))
    fns = {"fwd": lambda: run.forward(X), "adj": adjoint}
    sc = None if stepped is None else stepped.scheme  # None: forward and adjoint only

    def own():  # the scheme's step in a plain loop
        s = sc.start(X.T)
        for _ in range(run.steps):
            s = sc.step(s)
        return sc.field(s)

    if sc is not None:
        fns["own"] = own
    lu = None if sc is None else sc.lu  # an implicit scheme: a factorized A (explicit ones declare None)
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
    out.update(forward_s=t["fwd"], adjoint_vs_forward=t["adj"] / t["fwd"])
    if "own" in t:
        out["overhead_vs_bare"] = t["fwd"] / t["own"]
    if lu is not None:
        out.update(forward_vs_splu=t["fwd"] / t["bare"], solver=type(lu).__name__)
    if "modal" in t:
        ys = run.forward(X)
        out.update(modal_speedup=t["fwd"] / t["modal"], modal_modes=modal.k,
                   modal_agreement=float(np.linalg.norm(modal.forward(X) - ys) / np.linalg.norm(ys)))
    return out


def _stepper(method, problem, model, y):
    rule, model = make_rule(method, problem, problem.noise)[0], copy.deepcopy(model)
    state = [rule.init(problem, model)]

    def step():
        state[0], _ = rule.step(state[0], model, y)

    return step


def step_ratios(problem, model, batch: int = 32, repeats: int = 5, seed: int = 0) -> dict:
    """One step of the presets ``adam``, ``sip`` and ``hig`` on copies of ``model``, one batch:
    ``sip_vs_gd_step`` (SIP adds a forward and a local inverse, GD a forward and an adjoint),
    ``hig_step_s`` (the route the network declares: Kronecker on the default), and the float64
    size of the stacked Jacobian ``∂y/∂θ`` a dense route would build (GD and SIP never do)."""
    y = torch.as_tensor(problem.sample(batch, seed)[1], dtype=torch.float32)
    fit_preconditioning(model, y)  # as the trainer does before its first step
    t = interleaved({m: _stepper(m, problem, model, y) for m in ("adam", "sip", "hig")}, repeats)
    rows = batch * problem.operator.n_out
    n_params = sum(p.numel() for p in model.parameters() if p.requires_grad)
    return {"gd_step_s": t["adam"], "sip_step_s": t["sip"], "sip_vs_gd_step": t["sip"] / t["adam"],
            "hig_step_s": t["hig"], "hig_jacobian": [rows, n_params],
            "hig_jacobian_mb": rows * n_params * 8 / 2**20, "step_batch": batch}
