"""Amortization: what one reconstruction costs with the trained network and with each classical solve.

A network is worth training when it is at least as accurate as the classical solve and cheaper
per sample, so that the training time is paid back. For every classical solve the operator
supports (a constructor that refuses the operator drops the row): ``tikhonov_modal``
(:class:`~pdeinv.inverse.ModalTikhonov`) and ``tikhonov_cg`` (:class:`~pdeinv.inverse.TikhonovCG`, block
PCG on the normal equations) from ``x₀ = 0``, ``time_reversal`` (:class:`~pdeinv.inverse.TimeReversal`) from
``(y, v = 0)``, with α by Morozov's discrepancy principle at the problem's noise level (else the
default noise-free α), we time a batch and report the time per sample, the batch's mean x-error,
and the **break-even count** ``n* = t_train / (t_classical − t_network)`` (per-sample times): the
reconstructions after which training has paid for itself (``null`` when the network is not
cheaper). Times are interleaved minima over ``repeats`` rounds; a solve slower than ``SLOW_S`` per
batch is timed once.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from ..inverse import Discrepancy, ModalTikhonov, TikhonovCG, TimeReversal, default_alpha
from .timing import interleaved

#: a solve slower than this (seconds per batch) is timed once, not ``repeats`` times
SLOW_S = 2.0


def classical_solvers(problem) -> dict:
    """``{name: (Y -> X̂)}`` for the classical solves the scene's operator supports (module docstring)."""
    op = problem.operator
    alpha = (lambda: Discrepancy(problem.noise)) if problem.noise else (lambda: default_alpha(0.0))
    makers = {"tikhonov_modal": lambda: ModalTikhonov(op, alpha()), "time_reversal": lambda: TimeReversal(op),
              "tikhonov_cg": lambda: TikhonovCG(op, problem.disc.M, alpha())}
    out = {}
    for name, make in makers.items():
        try:
            solver = make()
        except ValueError:  # the operator lacks what this solve needs
            continue
        if isinstance(solver, TikhonovCG):
            solver.scale  # noqa: B018  a one-off setup (its λ_max estimate), not per sample
        out[name] = lambda Y, s=solver: s(Y, np.zeros((len(Y), op.n_in)))
    return out


def amortization(problem, model: torch.nn.Module, train_s: float, X, Y, repeats: int = 3,
                 batch: int = 32) -> dict:
    """Per-sample cost and x-error of ``model`` against each classical solve on ``(X, Y)``."""
    X, Y = np.asarray(X)[:batch], np.asarray(Y)[:batch]
    param = next(iter(model.parameters()))
    y_t = torch.as_tensor(Y, dtype=param.dtype)

    @torch.no_grad()
    def network():
        return model(y_t).double().numpy()

    solvers = classical_solvers(problem)
    err = {"network": float(np.mean(problem.relative_error(network(), X)))}
    once = {}
    for name, f in solvers.items():  # one timed call each; it also gives the x-error
        t0 = time.perf_counter()
        X_hat = f(Y)
        once[name] = time.perf_counter() - t0
        err[name] = float(np.mean(problem.relative_error(X_hat, X)))
    cheap = {k: (lambda f=f: f(Y)) for k, f in solvers.items() if once[k] < SLOW_S}
    times = {**once, **interleaved({"network": network, **cheap}, repeats=repeats)}
    t_net = times["network"] / len(Y)
    rows = {}
    for name, t in times.items():
        per = t / len(Y)
        gain = per - t_net
        rows[name] = {"s_per_sample": per, "x_err": err[name], "vs_network": per / t_net,
                      "break_even_samples": (None if name == "network" or gain <= 0
                                             else int(np.ceil(train_s / gain)))}
    return {"batch": len(Y), "train_s": train_s, "rows": rows,
            "alpha": f"Discrepancy({problem.noise:g})" if problem.noise else repr(default_alpha(0.0))}
