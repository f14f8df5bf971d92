"""Update rules compared at equal wall-clock time: same data, same seeds, same time budget.

Each candidate is a value (a factory from its swept hyper-parameter to an update
rule), never a branch on a method name. The hyper-parameter is chosen
independently per rule, as in the SIP and HIG papers ("best learning rate selected
independently for each optimizer"): every grid value trains for ``sweep_s`` seconds
with seed ``seed + 1000`` (other training data, and a *validation* set in place
of the test set), the lowest validation x-error wins, and only the winner trains
again, for ``budget_s`` seconds with ``seed`` on the reported test set.

Networks: Adam, SGD and SIP train the problem's default network. HIG and
Gauss–Newton (HIG with exponent −1) build the stacked Jacobian ``∂y/∂θ`` of
``batch · n_out`` rows × ``n_params`` columns every step; on a 961-unknown scene
with the default MLP (559 041 parameters) and batch 8 that is 7688 × 559 041
(tens of GB), and even a one-layer MLP of width 32 with batch 4 took 79 s per step (measured), so they train a
one-hidden-layer MLP of width 16 with batch 1 (``HIG_NET``). The JSON records each
method's network and batch. (HIG's matrix-free route, ``route="randomized"``, does run
on the default network, but at 2–9 s per step it makes only a handful of steps in
a 20-s budget; the small network gives the dense rules their best chance.)

Grids (half-decades; on heat_2d at 20 s the first run picked 3e-4 for Adam and SIP
and 0.03 for SGD, the grids' edges, so they were widened to put the winners inside):
Adam and SIP lr 1e-4…3e-3, SGD lr 3e-3…0.1, HIG η 0.1…1, Gauss–Newton η 0.1…1.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import torch

from ..methods import GD, HIG, SIP, NonFiniteError, adam, sgd
from ..nets import MLP
from ..train import Trainer

#: network and batch for the Jacobian-based rules (see the module docstring)
HIG_NET, HIG_BATCH = (16,), 1


@dataclass(frozen=True)
class Candidate:
    """``make(value) -> update rule``, the ``knob`` it sweeps over ``grid`` and its run size."""

    make: Callable[[float], object]
    grid: tuple[float, ...]
    default: float
    knob: str = "lr"
    hidden: tuple[int, ...] | None = None  # None: problem.model()
    batch_size: int = 32


CANDIDATES = {
    "adam": Candidate(lambda lr: GD(optimizer=adam(lr), name="adam"), (1e-4, 3e-4, 1e-3, 3e-3), 1e-3),
    "sgd": Candidate(lambda lr: GD(optimizer=sgd(lr), name="sgd"), (3e-3, 1e-2, 3e-2, 1e-1), 1e-2),
    "sip": Candidate(lambda lr: SIP(eta=1.0, optimizer=adam(lr)), (1e-4, 3e-4, 1e-3, 3e-3), 1e-3),
    "hig": Candidate(lambda eta: HIG(eta=eta, tau=1e-5), (0.1, 0.3, 1.0), 0.1, "eta",
                     HIG_NET, HIG_BATCH),
    "gauss_newton": Candidate(lambda eta: HIG(eta=eta, tau=1e-5, exponent=-1.0, name="gauss_newton"),
                              (0.1, 0.3, 1.0), 0.3, "eta", HIG_NET, HIG_BATCH),
}


def network(problem, hidden, seed: int) -> torch.nn.Module:
    torch.manual_seed(seed)
    if hidden is None:
        return problem.model()
    return MLP(problem.operator.n_out, problem.operator.n_in, hidden=tuple(hidden))


def train_once(problem, cand: Candidate, value: float, seed: int, budget_s: float,
               n_train: int, n_test: int, eval_every: int) -> dict:
    """One run; a NaN/Inf is an outcome (``x_err = inf``), not a crash."""
    batch = min(cand.batch_size, n_train)
    trainer = Trainer(problem, cand.make(value), network(problem, cand.hidden, seed), steps=None,
                      time_budget=budget_s, n_train=n_train, n_test=n_test, batch_size=batch,
                      seed=seed, eval_every=eval_every, progress=False)
    try:
        with warnings.catch_warnings():  # rejected steps are counted in the result, not printed
            warnings.simplefilter("ignore", RuntimeWarning)
            res = trainer.fit()
    except NonFiniteError as err:
        return {"x_err": math.inf, "y_err": math.inf, "wall_s": None, "outcome": "nan",
                "message": str(err), "curve": []}
    m = res.metrics
    curve = [[h["wall_s"], h["x_err"], h["y_err"]] for h in res.history if "x_err" in h]
    return {"x_err": m["x_err"], "y_err": m["y_err"], "wall_s": m["wall_s"], "steps": m["steps"],
            "step_s": m["step_s"], "n_params": m["n_params"], "rejected_steps": m["rejected_steps"],
            "outcome": "ok", "curve": curve}


def compare(problem, budget_s: float, seed: int = 0, sweep_s: float | None = None,
            n_train: int = 1024, n_test: int = 128, eval_every: int = 10, sweep: bool = True,
            candidates: dict | None = None) -> dict:
    """``{name: result}`` for every candidate; ``result[knob]`` is the value that won the sweep."""
    sweep_s = budget_s / 4 if sweep_s is None else sweep_s
    out = {}
    for name, cand in (candidates or CANDIDATES).items():
        tried = {}
        grid = cand.grid if sweep else (cand.default,)
        if len(grid) > 1:
            for v in grid:
                tried[v] = train_once(problem, cand, v, seed + 1000, sweep_s, n_train, n_test,
                                      eval_every)["x_err"]
        value = min(tried, key=lambda v: tried[v]) if tried else cand.default
        res = train_once(problem, cand, value, seed, budget_s, n_train, n_test, eval_every)
        out[name] = {**res, cand.knob: value, "sweep_val_x_err": {f"{k:g}": e for k, e in tried.items()},
                     "network": "problem.model()" if cand.hidden is None else f"MLP{cand.hidden}",
                     "batch_size": min(cand.batch_size, n_train)}
    return out
