"""Named method presets for the CLI: a dict of factories and per-problem defaults.

``make_rule("sip", "heat_1d", lr=3e-3)`` -> ``(SIP(...), {"lr": 3e-3, "eta": 1.0, ...})``.

How the defaults were chosen: one seed, default problem settings, MLP (256, 256)
with batch 32 for gd/adam/sip (300 steps on the 1-D scenes, 200 on heat_2d),
MLP (32, 32) with batch 8 for HIG (150 steps), 512 training and 128 test pairs;
the value with the lowest test x-error won (y-error as tie-break). Grid and
measured test x-errors (y-errors where x does not separate; "div" = diverged):

=========  =====================  ==========================================
problem    method                 tried -> x_err
=========  =====================  ==========================================
heat_1d    gd lr                  0.01 .43, **0.1 .36**, 1.0 div
heat_1d    adam lr                3e-4 .43, **1e-3 .35**, 3e-3 .33 (y .088 vs .065)
heat_1d    sip lr (η = 1)         3e-4 .25, **1e-3 .19**, 3e-3 .20
heat_1d    hig η (τ = 1e-5)       **0.1 .20**, 0.3 .31, 1.0 div
wave_1d    gd lr                  0.01 y .17, **0.1 y .073**, 1.0 div
wave_1d    adam lr                3e-4 y .071, **1e-3 y .054**, 3e-3 y .077 (x .78 all)
wave_1d    sip lr (η = 1)         same as adam to 1e-8 (see below)
wave_1d    hig η (τ = 1e-5)       **0.1 y .068**, 0.3 y .14, 1.0 div
heat_2d    gd lr                  **0.01 .56**, 0.1 div, 1.0 div
heat_2d    adam lr                3e-4 .46, **1e-3 .44**, 3e-3 .67
heat_2d    sip lr (η = 1)         3e-4 .33, **1e-3 .31**, 3e-3 .59
wave_s_2d  gd lr (300 steps)      1e-4 .71, 3e-4 .54, **1e-3 .42**, 3e-3 .43,
                                  1e-2 (GD_LR) .83 after a guard rollback at step 10
=========  =====================  ==========================================

The heat scenes' default network is now the whitened linear map (:mod:`pdeinv.nets`); SIP's
lr was re-swept on it (heat_2d, 20 s): 3e-4 .068, **1e-3 .032**, 3e-3 .091 (unstable). With
noisy observations SIP switches to SGD (``NOISY`` below).

τ = 1e-5 follows the HIG reference code (1e-5…1e-6 of σ_max), η = 1 for SIP is
the paper's full inverse step. On wave_1d (uniform 1-D mesh, M and K commute)
the time-reversal inverse turns Δy into (a multiple of) Pᵀ Δy, so SIP's proxy
gradient is GD's gradient up to scale and Adam, being scale-invariant, makes the
two runs coincide (test errors equal to 1e-10).
HIG on heat_2d/wave_2d (961 observations per sample) exceeds the Jacobian budget
with any useful batch: use a small ``--hidden`` and ``--batch-size``.
"""

from __future__ import annotations

from .._checks import positive
from .base import adam, sgd
from .gd import GD, GD_LR
from .hig import HIG
from .names import METHOD_NAMES
from .sip import SIP

#: SIP's proxy optimizer by name: (factory, normalize the proxy gradient by its curvature, default lr).
#: With ``normalize`` SGD's lr is in units of the Landweber step 1/λ_max (SIP's docstring): lr 1 on
#: every scene, no sweep. Adam is scale-invariant and keeps its own lr.
OPTIMIZERS = {"sgd": (sgd, True, 1.0), "adam": (adam, False, 1e-3)}

#: method name -> factory(hyper-parameters) -> update rule. No if-chains: add a line.
METHODS = {
    "gd": lambda hp: GD(optimizer=sgd(hp["lr"]), name="gd"),
    "adam": lambda hp: GD(optimizer=adam(hp["lr"]), normalize=False, name="adam"),  # scale-invariant
    "sip": lambda hp: SIP(eta=hp["eta"], optimizer=OPTIMIZERS[hp["optimizer"]][0](hp["lr"]),
                          normalize=OPTIMIZERS[hp["optimizer"]][1]),
    "hig": lambda hp: HIG(eta=hp["eta"], tau=hp["tau"]),
}
assert sorted(METHODS) == sorted(METHOD_NAMES), "add the method's name to methods/names.py too"

#: generic defaults per method (``batch_size`` and ``hidden`` size the run and the MLP)
GENERIC = {
    "gd": {"lr": GD_LR, "batch_size": 32},  # = pdeinv.GD(): normalized, lr in units of 1/λ_max
    "adam": {"lr": 1e-3, "batch_size": 32},
    # SIP: full batch (None: every training row), normalized SGD at lr 1, 100 steps (see SIP_DEFAULTS)
    "sip": {"lr": None, "eta": 1.0, "batch_size": None, "optimizer": "sgd", "steps": 100},
    "hig": {"eta": 0.1, "tau": 1e-5, "batch_size": 8, "hidden": (32, 32)},
}

#: per-problem overrides of GENERIC (none needed since the steps are normalized by the curvature)
PER_PROBLEM: dict[str, dict[str, dict]] = {}


def hyperparameters(method: str, problem: str, noise: float = 0.0, **overrides) -> dict:
    """Defaults for ``method`` on ``problem`` (with observation ``noise``), ``overrides`` applied
    (unknown keys refused)."""
    if method not in METHODS:
        raise ValueError(f"method={method!r} is not allowed; expected one of "
                         f"{', '.join(map(repr, METHODS))}")
    hp = {**GENERIC[method], **PER_PROBLEM.get(problem, {}).get(method, {})}
    hp.setdefault("hidden", None)
    bad = sorted(k for k, v in overrides.items() if v is not None and (k not in hp or k == "steps"))
    if bad:
        raise ValueError(f"{', '.join(bad)} does not apply to method {method!r} "
                         f"(its settings: {', '.join(sorted(hp))})")
    hp.update({k: v for k, v in overrides.items() if v is not None})
    if "optimizer" in hp and hp["optimizer"] not in OPTIMIZERS:
        raise ValueError(f"optimizer={hp['optimizer']!r} is not allowed; expected one of "
                         f"{', '.join(map(repr, OPTIMIZERS))}")
    if hp.get("lr", 0) is None:  # an optimizer (given or preset) brings its own lr unless one is given
        hp["lr"] = OPTIMIZERS[hp["optimizer"]][2]
    for key in ("lr", "eta"):  # torch would say "Invalid learning rate: nan" without naming the flag
        if key in hp:
            positive(hp[key], key)
    return hp


def make_rule(method: str, problem: str, noise: float = 0.0, **overrides):
    """``(rule, hyper-parameters)`` for a method name."""
    hp = hyperparameters(method, problem, noise, **overrides)
    return METHODS[method](hp), hp
