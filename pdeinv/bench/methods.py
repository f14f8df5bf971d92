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

Grids (half-decades; whenever a winner sat on a grid's edge the grid was moved to put it
inside): Adam lr 3e-4…1e-2 and SGD lr 0.03…1 (with the whitened default network on
heat_2d they picked 3e-3 and 0.1, then 0.3, the old grids' edges), SIP lr 1e-4…3e-3, HIG η 0.1…1,
Gauss–Newton η 0.1…1. The default network's alternatives (``NETWORKS``) train with SIP,
Adam lr 3e-4…3e-3, and the discrepancy stop on noisy data. ``sip_cli_default`` and
``hig_cli_default`` are what ``pdeinv train PROBLEM --method sip|hig`` runs without flags (the
preset rule, the default network, every training row per step, ``--stop auto``): never swept. The
swept ``hig`` and ``gauss_newton`` rows keep the small MLP: their dense Jacobian routes are what
they measure (the default networks take the Kronecker route, :mod:`pdeinv.methods.hig_kron`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import torch

from ..checkpoint import network_identity
from ..methods import GD, HIG, SIP, NonFiniteError, adam, sgd
from ..methods.presets import make_rule
from ..nets import MLP, whitened
from ..stopping import DiscrepancyStop
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
    hidden: tuple[int, ...] | str | None = None  # None: problem.model(); a str: NETWORKS[str]
    batch_size: int = 32
    stop: Callable | None = None  # problem -> stopping rule (or None)
    preset: str | None = None  # a method name: the rule `pdeinv train --method NAME` builds (make unused)


def _noisy_stop(problem):
    return DiscrepancyStop() if problem.noise else None


def _cli_stop(problem):
    """The stopping rule of ``--stop auto`` (the discrepancy stop only where no target is fitted)."""
    from ..commands.train import STOPS

    return STOPS["auto"](problem)


#: ``batch_size`` of a candidate that takes every training row (the SIP and HIG presets)
FULL = 2**62


#: alternative networks the methods section compares with the default (module docstring)
NETWORKS = {
    "mlp_standardized": lambda p: MLP(p.operator.n_out, p.operator.n_in),
    "whitened_linear": whitened("linear"),
    "whitened_mlp": whitened("mlp"),
}


CANDIDATES = {
    # the CLI defaults (preset rule, problem.model(), full batch, --stop auto): never swept
    "sip_cli_default": Candidate(None, (), 0.0, "lr", None, FULL, _cli_stop, "sip"),
    "hig_cli_default": Candidate(None, (), 0.0, "eta", None, FULL, _cli_stop, "hig"),
    "adam": Candidate(lambda lr: GD(optimizer=adam(lr), name="adam"), (3e-4, 1e-3, 3e-3, 1e-2), 1e-3),
    "sgd": Candidate(lambda lr: GD(optimizer=sgd(lr), name="sgd"), (3e-2, 1e-1, 3e-1, 1.0), 1e-2),
    "sip": Candidate(lambda lr: SIP(eta=1.0, optimizer=adam(lr)), (1e-4, 3e-4, 1e-3, 3e-3), 1e-3),
    "hig": Candidate(lambda eta: HIG(eta=eta, tau=1e-5), (0.1, 0.3, 1.0), 0.1, "eta",
                     HIG_NET, HIG_BATCH),
    "gauss_newton": Candidate(lambda eta: HIG(eta=eta, tau=1e-5, exponent=-1.0, name="gauss_newton"),
                              (0.1, 0.3, 1.0), 0.3, "eta", HIG_NET, HIG_BATCH),
}


#: alternatives to the default network, trained with SIP (Adam, swept lr) at the same budget
for _net in NETWORKS:
    CANDIDATES[f"sip_{_net}"] = Candidate(lambda lr: SIP(eta=1.0, optimizer=adam(lr)), (3e-4, 1e-3, 3e-3),
                                          1e-3, "lr", _net, 32, _noisy_stop)


def network(problem, hidden, seed: int) -> torch.nn.Module:
    torch.manual_seed(seed)
    if hidden is None:
        return problem.model()
    if isinstance(hidden, str):
        return NETWORKS[hidden](problem)
    return MLP(problem.operator.n_out, problem.operator.n_in, hidden=tuple(hidden))


def train_once(problem, cand: Candidate, value: float, seed: int, budget_s: float,
               n_train: int, n_test: int, eval_every: int) -> dict:
    """One run; a NaN/Inf is an outcome (``x_err = inf``), not a crash."""
    batch = min(cand.batch_size, n_train)
    make = cand.make if cand.preset is None else \
        (lambda _: make_rule(cand.preset, problem, problem.noise)[0])
    trainer = Trainer(problem, make(value), network(problem, cand.hidden, seed), steps=None,
                      time_budget=budget_s, n_train=n_train, n_test=n_test, batch_size=batch,
                      seed=seed, eval_every=eval_every, progress=False,
                      stop=cand.stop(problem) if cand.stop else None)
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
            "stopped_by": m["stopped_by"], "outcome": "ok", "curve": curve, "model": res.model}


def compare(problem, budget_s: float, seed: int = 0, sweep_s: float | None = None,
            n_train: int = 1024, n_test: int = 128, eval_every: int = 10, sweep: bool = True,
            candidates: dict | None = None) -> dict:
    """``{name: result}`` for every candidate; ``result[knob]`` is the value that won the sweep."""
    sweep_s = budget_s / 4 if sweep_s is None else sweep_s
    out = {}
    default_net = network_identity(network(problem, None, seed))
    for name, cand in (candidates or CANDIDATES).items():
        alternative = isinstance(cand.hidden, str)
        if alternative and network_identity(network(problem, cand.hidden, seed)) == default_net:
            continue  # the default network: already benched as "sip"
        tried = {}
        grid = cand.grid if sweep and cand.grid else (cand.default,)
        if len(grid) > 1:
            for v in grid:
                tried[v] = train_once(problem, cand, v, seed + 1000, sweep_s, n_train, n_test,
                                      eval_every)["x_err"]
        value = min(tried, key=lambda v: tried[v]) if tried else cand.default
        res = train_once(problem, cand, value, seed, budget_s, n_train, n_test, eval_every)
        chosen = ({"preset": make_rule(cand.preset, problem, problem.noise)[1]} if cand.preset
                  else {cand.knob: value})
        out[name] = {**res, **chosen, "sweep_val_x_err": {f"{k:g}": e for k, e in tried.items()},
                     "network": ("problem.model()" if cand.hidden is None else cand.hidden
                                 if isinstance(cand.hidden, str) else f"MLP{cand.hidden}"),
                     "batch_size": min(cand.batch_size, n_train)}
    return out
