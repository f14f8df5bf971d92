"""Named method presets, for the CLI and for Python alike: a dict of factories and the defaults every
scene shares.

``make_rule("sip", "heat_1d", lr=3e-3)`` -> ``(SIP(...), {"lr": 3e-3, "eta": 1.0, ...})``.

One table for both entry points: ``pdeinv train --method M`` and ``pdeinv.train(problem, rule)`` (or
``pdeinv.Trainer``) take a run's ``steps``, ``batch_size`` and, for the default network,
``rows_per_component`` from :data:`GENERIC` by the rule's ``name`` (:func:`run_defaults`), so
``pdeinv.train(p, pdeinv.SIP())`` runs what ``pdeinv train --method sip`` runs (30 full-batch steps).
A rule whose name is not in the table (a user's own) gets :data:`DEFAULT_STEPS` steps of
:data:`DEFAULT_BATCH` rows.

No per-scene table: every step size follows from the maths.

* **sip**: η = 1 (the paper's full inverse step), the local inverse of what the network can produce:
  on the prior-decoder network (the default where the operator is not reversible,
  :func:`pdeinv.nets.default_model`) the Tikhonov solve in the decoder's span at rounding-level α
  (:class:`pdeinv.inverse.decoder.DecoderTikhonov`), else the problem's own (a Tikhonov filter on
  the operator's spectral basis at rounding-level α, :func:`pdeinv.inverse.default_inverse`),
  plain SGD at lr 1 on the proxy gradient normalized by its largest curvature (the Landweber step,
  :class:`~.sip.SIP`), **every training row in each step** (``batch_size=None``) and 30 steps (the
  training loss reaches rounding within a few steps on every full-rank scene).
  On the whitened linear default network the full-batch proxy's Hessian is the identity on the
  kept directions, so one step solves it; minibatches leave an unconverged error along the trailing
  whitened directions, which test data amplify (wave_2d: x-error 0.35 against < 5e-6 full batch). Noisy data
  need no other setting: the trainer fits a denoised target (:mod:`pdeinv.methods.targets`).
  On a network that is not linear in θ (``--hidden``) the proxy is a nonconvex fit: Adam at 1e-3 on
  minibatches of 32 for 1000 steps, the SIP paper's optimizer (:data:`SIP_MLP`).
* **gd**: plain SGD at lr 1 on the gradient normalized by ``λ_max(PᵀP)·λ_max(JᵀJ/B)`` (the stable
  step, :class:`~.gd.GD`): stable on every scene, slow on smoothing ones (it is Landweber).
* **adam**: lr 1e-3 on the raw gradient (Adam is scale-invariant), batch 32.
* gd and adam train the default network with **one whitened direction per 8 training rows**
  (``rows_per_component=8``, :class:`~pdeinv.nets.whitening.Whitening`): a first-order rule stops
  far from the least-squares map, and whatever weight it leaves on the trailing whitened
  directions is amplified on new data wherever the observations fill about as many directions
  as there are training rows (wave_2d: 961 of 1024; the sample covariance's smallest eigenvalues
  are then ~1e-3 of the true ones, Marchenko–Pastur; Adam on wave_2d: x-error 42 with all directions,
  0.10 with the cap). SIP and HIG solve their linear problems exactly and generalize with every
  direction.
* **hig**: the exact Kronecker route on the default network (:mod:`.hig_kron`), every training row
  in each step, η 1 on the normalized step (the leading direction solved per step, :class:`~.hig.HIG`),
  τ 1e-6 of σ_max (the HIG reference code's range), 1000 steps. The rows are the same in every step,
  so after the first a step costs no feature map and no physics (:mod:`.hig_fixed`).
  The half-inverse moves a direction of relative singular value ρ by ``ρ^½`` of the way per step, so the
  weak modes of the smoothing scenes keep converging long after the strong ones (hence 1000 steps).
  Minibatches (the Gram route, :func:`.hig_kron.direction_rows`) leave weight on the trailing whitened
  directions, which test data amplify (Marchenko–Pastur, as for Adam), and batches of 64 made
  wave_sensors_2d blow up: the full batch is the preset on every scene.

Accuracy against best-α Tikhonov (``benchmarks/accuracy.py``): benchmarks/notes/results-history.md.
"""

from __future__ import annotations

from .._checks import positive
from ..nets.protocol import declared as nets_declared
from .base import adam, sgd
from .gd import GD, GD_LR
from .hig.rule import HIG
from .names import METHOD_NAMES
from .protocol import declared
from .sip import SIP
from .supervised import Supervised

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
    "supervised": lambda hp: Supervised(optimizer=sgd(hp["lr"])),  # needs x (targets.TrueFields)
}
assert sorted(METHODS) == sorted(METHOD_NAMES), "add the method's name to methods/names.py too"

#: generic defaults per method (``batch_size`` and ``hidden`` size the run and the MLP)
GENERIC = {
    # first-order rules: the default network with one whitened direction per 8 rows (docstring)
    "gd": {"lr": GD_LR, "batch_size": 32, "rows_per_component": 8},  # = pdeinv.GD(): lr in units of 1/λ_max
    "adam": {"lr": 1e-3, "batch_size": 32, "rows_per_component": 8},
    # SIP: full batch (None: every training row), normalized SGD at lr 1, 30 steps (module docstring)
    "sip": {"lr": None, "eta": 1.0, "batch_size": None, "optimizer": "sgd", "steps": 30},
    # HIG: the exact Kronecker route on the default network, full batch, η 1 on the normalized step
    "hig": {"eta": 1.0, "tau": 1e-6, "batch_size": None, "steps": 1000},
    # supervised on the true fields (x in the data): plain SGD at lr 1 on the full batch. On the whitened
    # linear map the x-loss's Hessian is the identity on the kept directions, so the first step is the
    # least-squares fit of x on the whitened y (the empirical linear MMSE); heat_boxes n=32: 0.264 after
    # 1 and 5 steps, heat_1d 0.0026 (SIP 0.0040). Adam at 1e-3, batch 32, 1000 steps on 128 components
    # stopped at 0.383 on heat_boxes 64².
    "supervised": {"lr": 1.0, "batch_size": None, "steps": 10},
}

#: HIG's batch on an MLP (``--hidden``): the full batch is the preset only for the networks linear in θ
#: (the Kronecker route sums the rows once); an MLP's dense Jacobian has ``batch · r`` rows, and the
#: full batch took 64 s per step on heat_1d with MLP (16,) (18 432 × 2 095, SVD) against ~0.05 s at 32
HIG_MLP_BATCH = 32

#: HIG's steps where the physics is nonlinear: no Kronecker route (it needs a fixed ``P``), so each step
#: forms the stacked Jacobian of :data:`HIG_MLP_BATCH` rows through the physics' tangent and decomposes
#: it (sine_gordon_1d: 2 s per step, a 2 016 × 2 016 Gram matrix; the full batch took 88 s for its first
#: step). 100 steps: x-error 0.228 of the linear part (SIP's 30 full-batch steps 0.207, Adam 0.330)
HIG_NONLINEAR_STEPS = 100

#: HIG's η where the physics is nonlinear (:data:`HIG_NONLINEAR_STEPS`' minibatches of 32): a step at η 1
#: fits its own 32 rows (allen_cahn_1d: their loss to 0.14–0.30 of its value) and moves the rest the other
#: way (held-out loss ×1.17–1.72 from the third step on; the run diverged at step 29 and ended at 11.9 after
#: the correction); η < 1 averages the directions of successive batches. Linear part after 100 steps (the
#: prior decoder, no correction), η 0.3 / 0.5 / 1: allen_cahn_1d 0.358 / 0.408 / diverged, sine_gordon_1d
#: 0.203 / 0.211 / 0.222 (SIP's 30 full-batch steps 0.346 and 0.207, Adam 0.440 and 0.330)
HIG_NONLINEAR_ETA = 0.3


def _nonlinear(problem) -> bool:
    from ..physics.nonlinear import is_linear

    return problem is not None and not isinstance(problem, str) and not is_linear(problem.operator)


#: the value of ``Trainer(steps=..., batch_size=...)`` that means "the rule's preset" (their default)
PRESET = "preset"

#: steps of a method whose preset names none (gd, adam, a user's rule): ``pdeinv train --steps``'s default
DEFAULT_STEPS = 1000
#: rows per step of a rule not in :data:`GENERIC` (a user's own)
DEFAULT_BATCH = 32

#: SIP's preset on a network that is not linear in its parameters (``--hidden``): the SIP paper's proxy
#: optimizer, Adam at its own lr 1e-3 on minibatches of 32, :data:`DEFAULT_STEPS` steps (what the user sets
#: is kept). Normalized full-batch SGD solves the proxy of a network linear in θ in one step; on an MLP it is
#: a Landweber iteration on a nonconvex fit, and its 30 steps left it far from the targets. MLP (256, 256),
#: no prior fit, one thread, x-error with this preset / the linear-network preset / Adam's own: heat_2d
#: 0.267 / 0.641 / 0.391, sine_gordon_1d 0.229 / 0.609 / 0.234
SIP_MLP = {"optimizer": "adam", "batch_size": 32, "steps": DEFAULT_STEPS}


def preset_steps(hp: dict | None, time_budget: float | None) -> int | None:
    """The steps of a run that did not say: none with a time budget (it ends the run), else the
    preset's (``hp["steps"]``), else :data:`DEFAULT_STEPS`."""
    return None if time_budget is not None else (hp or {}).get("steps") or DEFAULT_STEPS


def run_defaults(rule, model=None, problem=None) -> dict:
    """``{"steps", "batch_size", "rows_per_component"}`` of ``rule``'s preset (looked up by
    ``rule.name``), what :class:`pdeinv.Trainer` uses for the arguments it was not given. On a network
    that is not linear in its parameters (an MLP, the U-Net) HIG takes :data:`HIG_MLP_BATCH` rows and SIP
    :data:`SIP_MLP`'s minibatches and steps, as ``pdeinv train --hidden W`` / ``--net unet`` do; HIG on
    nonlinear physics also :data:`HIG_NONLINEAR_STEPS` steps."""
    name = declared(rule).name
    hp = GENERIC.get(name)
    if hp is None:
        return {"steps": DEFAULT_STEPS, "batch_size": DEFAULT_BATCH, "rows_per_component": None}
    batch, steps = hp.get("batch_size"), hp.get("steps") or DEFAULT_STEPS
    nonlinear_net = model is not None and nets_declared(model).linear_in_parameters() is None
    if name == "hig" and nonlinear_net:  # its stacked Jacobian grows with the batch
        batch = HIG_MLP_BATCH
    if name == "sip" and nonlinear_net:  # the paper's optimizer on a network not linear in θ (SIP_MLP)
        batch, steps = SIP_MLP["batch_size"], SIP_MLP["steps"]
    if name == "hig" and _nonlinear(problem):
        batch, steps = HIG_MLP_BATCH, HIG_NONLINEAR_STEPS
    return {"steps": steps, "batch_size": batch, "rows_per_component": hp.get("rows_per_component")}


#: the settings ``pdeinv train`` has a flag for (``batch_size``: ``--batch-size``)
FLAGS = ("lr", "eta", "tau", "batch_size", "hidden", "optimizer", "steps")


def _flagged(key: str) -> str:
    """``key`` and, where the CLI has one, its flag: ``"lr (--lr)"``."""
    return f"{key} (--{key.replace('_', '-')})" if key in FLAGS else key


def hyperparameters(method: str, problem, noise: float = 0.0, linear_net: bool = True, **overrides) -> dict:
    """Defaults for ``method`` on ``problem`` (a :class:`~pdeinv.Problem` or its name) with observation
    ``noise``, ``overrides`` applied (unknown keys refused). ``linear_net=False``: the network is not
    linear in its parameters (``--net unet``; the MLP of ``hidden`` always), which takes the presets of
    :data:`SIP_MLP` and :data:`HIG_MLP_BATCH`."""
    if method not in METHODS:
        raise ValueError(f"method={method!r} is not allowed; expected one of "
                         f"{', '.join(map(repr, METHODS))}")
    hp = dict(GENERIC[method])
    hp.setdefault("hidden", None)
    hp.setdefault("rows_per_component", None)
    bad = sorted(k for k, v in overrides.items() if v is not None and (k not in hp or k == "steps"))
    if bad:
        takes = sorted({k for k in hp if k in FLAGS} | {"steps"})  # the ones a user can set
        raise ValueError(f"{', '.join(map(_flagged, bad))} does not apply to method {method!r} "
                         f"(--method {method}); it takes {', '.join(map(_flagged, takes))}")
    hp.update({k: v for k, v in overrides.items() if v is not None})
    nonlinear_net = hp["hidden"] is not None or not linear_net
    if method == "hig" and nonlinear_net and overrides.get("batch_size") is None:
        hp["batch_size"] = HIG_MLP_BATCH  # an MLP's stacked Jacobian grows with the batch (HIG_MLP_BATCH)
    if method == "sip" and nonlinear_net:  # the paper's optimizer on an MLP or a U-Net (SIP_MLP)
        hp.update({k: v for k, v in SIP_MLP.items() if overrides.get(k) is None})
    if method == "hig" and _nonlinear(problem):  # no Kronecker route (HIG_NONLINEAR_STEPS, _ETA)
        hp["batch_size"] = overrides.get("batch_size") or HIG_MLP_BATCH
        hp["steps"] = HIG_NONLINEAR_STEPS
        hp["eta"] = overrides.get("eta") or HIG_NONLINEAR_ETA
    if "optimizer" in hp and hp["optimizer"] not in OPTIMIZERS:
        raise ValueError(f"optimizer={hp['optimizer']!r} is not allowed; expected one of "
                         f"{', '.join(map(repr, OPTIMIZERS))}")
    if hp.get("lr", 0) is None:  # an optimizer (given or preset) brings its own lr unless one is given
        hp["lr"] = OPTIMIZERS[hp["optimizer"]][2]
    for key in ("lr", "eta"):  # torch would say "Invalid learning rate: nan" without naming the flag
        if key in hp:
            positive(hp[key], key)
    return hp


def make_rule(method: str, problem, noise: float = 0.0, linear_net: bool = True, **overrides):
    """``(rule, hyper-parameters)`` for a method name (``linear_net``: :func:`hyperparameters`)."""
    hp = hyperparameters(method, problem, noise, linear_net, **overrides)
    return METHODS[method](hp), hp
