"""Update rules compared at equal wall-clock time: same data, same seeds, same time budget.

Every candidate is a preset of ``pdeinv train --method NAME`` (:func:`~pdeinv.methods.presets.make_rule`:
rule, batch, network, ``--stop auto``) with one hyper-parameter swept; no rule is built here. As in
the SIP and HIG papers ("best learning rate selected independently for each optimizer") every grid
value (× the preset's) trains ``sweep_s`` seconds with seed ``seed + 1000`` (other training data, a
*validation* set), the lowest validation x-error wins, and the winner trains ``budget_s`` seconds
with ``seed`` on the reported test set. Rows: ``sip_cli_default``, ``hig_cli_default`` (the presets
as shipped, never swept), ``adam``, ``sgd`` (the ``gd`` preset: SGD on the curvature-normalized
gradient), ``sip`` (with Adam), ``hig`` (the default network, every training row per step, the
Kronecker route), ``gauss_newton`` (the HIG preset with exponent −1) and the default network's
alternatives (:data:`NETWORKS`, SIP with Adam). The JSON has each row's preset, value, network, batch.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass, field

import torch

from ..methods import NonFiniteError
from ..methods.presets import hyperparameters, make_rule
from ..nets import MLP, whitened
from ..training.checkpoint import network_identity
from ..training.trainer import Trainer


@dataclass(frozen=True)
class Candidate:
    """The preset ``method`` with ``fixed`` overrides, ``knob`` swept over ``grid`` × its value, ``rule``
    fields changed (e.g. HIG's exponent), ``net``: a :data:`NETWORKS` name for the preset's network."""

    method: str
    knob: str = "lr"
    grid: tuple[float, ...] = ()
    fixed: dict = field(default_factory=dict)
    rule: dict = field(default_factory=dict)
    net: str | None = None


#: alternative networks the methods section compares with the default (module docstring)
NETWORKS = {
    "mlp_standardized": lambda p: MLP(p.operator.n_out, p.operator.n_in),
    "whitened_linear": whitened("linear"),
    "whitened_mlp": whitened("mlp"),
}

_SIP_ADAM = {"optimizer": "adam"}
CANDIDATES = {
    "sip_cli_default": Candidate("sip"),
    "hig_cli_default": Candidate("hig", "eta"),
    "adam": Candidate("adam", "lr", (0.3, 1.0, 3.0, 10.0)),
    "sgd": Candidate("gd", "lr", (0.3, 1.0, 3.0)),
    "sip": Candidate("sip", "lr", (0.1, 0.3, 1.0, 3.0), _SIP_ADAM),
    "hig": Candidate("hig", "eta", (0.3, 1.0)),
    "gauss_newton": Candidate("hig", "eta", (0.3, 1.0), rule={"exponent": -1.0, "name": "gauss_newton"}),
    **{f"sip_{net}": Candidate("sip", "lr", (0.3, 1.0, 3.0), _SIP_ADAM, net=net) for net in NETWORKS},
}


def setup(problem, cand: Candidate, scale: float = 1.0, seed: int = 0):
    """``(rule, hyper-parameters, network)`` of ``cand`` with its knob at ``scale`` × the preset's."""
    value = hyperparameters(cand.method, problem, problem.noise, **cand.fixed)[cand.knob] * scale
    rule, hp = make_rule(cand.method, problem, problem.noise, **cand.fixed, **{cand.knob: value})
    rule = dataclasses.replace(rule, **cand.rule) if cand.rule else rule
    torch.manual_seed(seed)
    cap = hp["rows_per_component"] if problem.model_factory is None else None  # as pdeinv train does
    model = (NETWORKS[cand.net](problem) if cand.net else
             problem.model(**({"rows_per_component": cap} if cap else {})))
    return rule, hp, model


def train_once(problem, cand: Candidate, scale: float, seed: int, budget_s: float,
               n_train: int, n_test: int, eval_every: int) -> dict:
    """One run (with ``--stop auto``); a NaN/Inf is an outcome (``x_err = inf``), not a crash."""
    from ..training.stopping import chosen

    rule, hp, model = setup(problem, cand, scale, seed)
    batch = None if hp["batch_size"] is None else min(hp["batch_size"], n_train)
    trainer = Trainer(problem, rule, model, steps=None, time_budget=budget_s, n_train=n_train,
                      n_test=n_test, batch_size=batch, seed=seed, eval_every=eval_every, progress=False,
                      stop=chosen(problem, None, model), prior=None)  # the rules alone, at equal time
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
            "stopped_by": m["stopped_by"], "outcome": "ok", "curve": curve, "model": res.model,
            "batch_size": batch if batch is not None else n_train, cand.knob: hp[cand.knob]}


def compare(problem, budget_s: float, seed: int = 0, sweep_s: float | None = None,
            n_train: int = 1024, n_test: int = 128, eval_every: int = 10, sweep: bool = True,
            candidates: dict | None = None) -> dict:
    """``{name: result}`` for every candidate; ``result[knob]`` is the value that won the sweep."""
    sweep_s = budget_s / 4 if sweep_s is None else sweep_s
    out = {}
    default_net = network_identity(problem.model())
    for name, cand in (candidates or CANDIDATES).items():
        if cand.net and network_identity(NETWORKS[cand.net](problem)) == default_net:
            continue  # the default network: already benched as "sip"
        tried = {s: train_once(problem, cand, s, seed + 1000, sweep_s, n_train, n_test, eval_every)["x_err"]
                 for s in (cand.grid if sweep and len(cand.grid) > 1 else ())}
        scale = min(tried, key=lambda s: tried[s]) if tried else 1.0
        res = train_once(problem, cand, scale, seed, budget_s, n_train, n_test, eval_every)
        out[name] = {**res, "preset": cand.method, **cand.fixed, **cand.rule,
                     "sweep_val_x_err": {f"{res[cand.knob] / scale * s:g}": e for s, e in tried.items()},
                     "network": cand.net or "problem.model()"}
    return out
