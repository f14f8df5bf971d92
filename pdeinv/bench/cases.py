"""The stress cases for one problem: sweeps over physics, numerics and update-rule settings.

Sweeps (quick mode: a subset of the values; a sweep applies where the scene has its setting):
``kappaT`` over four decades; ``noise`` 0–10 % (linear-MMSE and best-α Tikhonov x-errors);
``dt_<scheme>`` from one step to 10⁴ against the exact mode (BE/CN/Newmark are unconditionally
stable: ``growth = ‖u_T‖_M/‖u₀‖_M`` must stay bounded); ``explicit`` (heat: refused; wave:
leapfrog at 0.9× and 1.1× its CFL limit, the latter refused); ``mesh_n`` refinement with the
dot-product test; ``precision`` float32 vs float64 (torch bridge and training); ``hig_tau``,
``hig_tau_default`` and ``sip_eta``; ``alpha``: Tikhonov down to 1e-12 s_max², with 0 and 1 % noise.

Training cases run on a coarse copy of the scene (``n = 8``) so they finish in seconds.
``hig_tau`` trains HIG (η = 1) on an MLP (4,) with batch 16: 784 Jacobian rows against 445
parameters, so J has (near-)zero singular values, where the HIG paper shows the full inversion
τ = 0 explode; ``hig_tau_default`` sweeps τ for ``--method hig`` as shipped (the preset: the
default network, every training row per step, the Kronecker route). ``sip_eta``: SIP with plain
SGD (lr 0.1), since Adam is scale-invariant (η would cancel out).
"""

from __future__ import annotations

import warnings
from functools import cache, partial

import numpy as np
import torch

from ..methods import GD, HIG, SIP, adam, sgd
from ..methods.presets import make_rule
from ..nets import MLP
from ..physics.bridge import apply
from ..physics.nonlinear import is_linear
from ..problem.definition import load_problem
from ..training import references as refs
from ..training.trainer import Trainer
from ..training.verdict import FailedRun
from .forward import exact_factor
from .stress import Case

FULL = {"kappaT": (1e-3, 1e-2, 1e-1, 1.0), "noise": (0.0, 0.01, 0.03, 0.1), "n": (4, 8, 16, 32, 64),
        "steps": (1, 10, 100, 1000, 10000), "precision": ("float32", "float64"),
        "tau": (0.0, 1e-8, 1e-6, 1e-4, 1e-2), "eta": (0.1, 0.5, 1.0, 2.0, 5.0),
        "alpha": (1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12)}
QUICK = {"kappaT": (1e-2, 1.0), "noise": (0.0, 0.1), "steps": (1, 10, 100), "n": (4, 8),
         "precision": ("float32", "float64"), "tau": (0.0, 1e-2), "eta": (1.0, 5.0), "alpha": (1e-2, 1e-12)}


def mode_error(problem) -> dict:
    """Forward error against the exact mode solution and ``growth = ‖P u₀‖_M / ‖u₀‖_M``."""
    disc = problem.disc
    x0 = np.prod(np.sin(np.pi * disc.points), axis=0)[None]
    y = problem.operator.forward(x0)
    out = {"growth": float(disc.norm(y)[0] / disc.norm(x0)[0])}
    factor = exact_factor(problem)
    if factor is not None:
        out["forward_err"] = float(disc.relative_error(y, factor * x0)[0])
    return out


def dot_err(op, seed: int = 0, dtype=torch.float64) -> float:
    """``|⟨Px, r⟩ − ⟨x, Pᵀr⟩| / (‖Px‖‖r‖)`` through the torch bridge in ``dtype``; for nonlinear physics
    (declared) the tangent's, ``|⟨P'(x)v, r⟩ − ⟨v, P'(x)ᵀr⟩| / (‖P'(x)v‖‖r‖)`` by ``jvp``/``vjp``
    (float64)."""
    rng = np.random.default_rng(seed)
    if not is_linear(op):
        x, v = 0.5 * rng.standard_normal((2, 3, op.n_in))
        r = rng.standard_normal((3, op.n_out))
        jv, vj = op.jvp(x, v), op.vjp(x, r)
        return float(abs(np.sum(jv * r) - np.sum(v * vj)) / (np.linalg.norm(jv) * np.linalg.norm(r)))
    x = torch.tensor(rng.standard_normal((3, op.n_in)), dtype=dtype, requires_grad=True)
    r = torch.tensor(rng.standard_normal((3, op.n_out)), dtype=dtype)
    y = apply(op, x)
    (g,) = torch.autograd.grad((y * r).sum(), x)
    with torch.no_grad():
        return float(abs((y * r).sum() - (x * g).sum()) / (y.norm() * r.norm()))


def _norm(model) -> float:
    return float(torch.cat([p.detach().double().flatten() for p in model.parameters()]).norm())


def train(problem, rule, steps, hidden=(256, 256), batch=8, dtype=None) -> dict:
    """A short run of a standardized tanh MLP of ``hidden`` widths (``param_growth = ‖θ_end‖ / ‖θ_0‖``:
    its output stays bounded while its first layer blows up), or with ``hidden=None`` of the problem's
    default network (zero at start: ``param_norm``); ``loss_growth``: last 3 batch losses / first 3."""
    torch.manual_seed(0)
    model = problem.model() if hidden is None else MLP(problem.operator.n_out, problem.operator.n_in,
                                                       hidden=tuple(hidden))
    model = model if dtype is None else model.to(dtype)
    theta0 = _norm(model)
    with warnings.catch_warnings():  # a run no better than zero is the case's outcome (x_err watched)
        warnings.simplefilter("ignore", FailedRun)
        res = Trainer(problem, rule, model, steps=steps, n_train=64, n_test=16, batch_size=batch,
                      eval_every=steps, progress=False, dtype=dtype, prior=None).fit()
    losses = [h["loss"] for h in res.history]
    out = {"x_err": res.metrics["x_err"], "y_err": res.metrics["y_err"],
           "loss_growth": float(np.mean(losses[-3:]) / np.mean(losses[:3]))}
    grown = {"param_norm": _norm(model)} if hidden is None else {"param_growth": _norm(model) / theta0}
    return {**out, **grown}


def cases(name: str, overrides: dict, quick: bool = False) -> list[Case]:
    """All stress cases for problem ``name`` with ``overrides`` (none runs until classified)."""
    v = QUICK if quick else FULL
    load = partial(load_problem, name, **overrides)
    base = load()
    heat = "kappa" in base.settings  # a sweep applies where the scene has its setting
    has_n = "n" in base.settings and not base.settings.get("mesh")
    small = partial(load, n=8) if has_n else load
    n_tr, n_te = (32, 8) if quick else (256, 32)
    return (_physics_cases(load, base, v, heat, has_n, n_tr, n_te)
            + _training_cases(load, base, v, small, quick, n_te))


def _physics_cases(load, base, v, heat, has_n, n_tr, n_te) -> list[Case]:
    """κT, noise, time step, explicit schemes and mesh sweeps: the physics and its references. On
    nonlinear physics (declared) the sweeps that need a matrix (the linear references of ``noise``, the
    explicit schemes of the linear scenes) are not built, and ``backend`` is set only where the scene has
    that setting."""
    out = []
    linear = is_linear(base.operator)
    steps_backend = {"backend": "steps"} if "backend" in base.settings else {}

    def kappa(kt):
        p = load(kappa=kt / base.settings["T"])
        x = np.prod(np.sin(np.pi * p.disc.points), axis=0)[None]
        back = p.inverse(p.operator.forward(x), x)
        kind = p.operator.kind if is_linear(p.operator) else type(p.operator).__name__
        return {**mode_error(p), "dot_err": dot_err(p.operator), "backend": kind,
                "roundtrip_err": float(p.relative_error(back, x)[0])}

    if heat:
        out += [Case("kappaT", kt, partial(kappa, kt)) for kt in v["kappaT"]]

    def noise(level):
        p = load(noise=level)
        (x, _), (xt, yt) = p.sample(n_tr, 1), p.sample(n_te, 2)
        r = refs.references(p, x, xt, yt)
        return {"mmse_x_err": r["mmse_x_err"], "tikhonov_best_x_err": r["tikhonov_best_x_err"]}

    if linear:
        out += [Case("noise", lv, partial(noise, lv)) for lv in v["noise"]]

    for scheme in ("be", "cn") if heat else (None,):
        extra = {"scheme": scheme, **steps_backend} if heat else {}
        label = f"dt_{scheme}" if heat else "dt_newmark"
        out += [Case(label, k, lambda k=k, e=extra: {**mode_error(load(steps=k, **e)),
                                                      "dt": base.settings["T"] / k}) for k in v["steps"]]
    if heat and linear:
        out.append(Case("explicit", "fe", lambda: mode_error(load(scheme="fe"))))
    elif linear:  # leapfrog just below and just above its CFL limit (the limit from a stable build)
        def leapfrog(factor):
            limit = load(scheme="leapfrog", steps=100 * base.settings["steps"]).operator.dt_max
            steps = max(1, round(base.settings["T"] / (factor * limit)))
            return {**mode_error(load(scheme="leapfrog", steps=steps)),
                    "dt_over_limit": base.settings["T"] / steps / limit}

        out += [Case("explicit", f"leapfrog_{f:g}x_cfl", partial(leapfrog, f)) for f in (0.9, 1.1)]

    def mesh(n):  # heat steps: the sweep is about the mesh, and n = 64 modal setup takes minutes
        p = load(n=n, **(steps_backend if heat else {}))
        return {**mode_error(p), "N": p.N, "dot_err": dot_err(p.operator)}

    if has_n:
        out += [Case("mesh_n", n, partial(mesh, n)) for n in v["n"]]
    return out


def _training_cases(load, base, v, small, quick, n_te) -> list[Case]:
    """Precision, HIG's τ, SIP's η and the Tikhonov α: short training runs and regularized solves."""
    out = []
    steps = 5 if quick else 30

    def precision(kind):
        dtype = {"float32": torch.float32, "float64": torch.float64}[kind]
        p = small()
        x = torch.tensor(p.sample(4, 0)[0], dtype=dtype)
        ref = p.operator.forward(x.double().numpy())
        bridge = float(np.linalg.norm(apply(p.operator, x).double().numpy() - ref) / np.linalg.norm(ref))
        return {**train(p, GD(optimizer=adam(1e-3)), steps, dtype=dtype), "bridge_rel_diff": bridge,
                "dot_err": dot_err(p.operator, dtype=dtype)}

    out += [Case("precision", k, partial(precision, k)) for k in v["precision"]]
    hig_steps = 2 if quick else 10  # τ = 0: ‖θ‖ grows ~7e7× within 2 steps (measured)
    out += [Case("hig_tau", t, lambda t=t: train(small(), HIG(eta=1.0, tau=t), hig_steps, (4,), 16))
            for t in v["tau"]]
    hig = lambda t: make_rule("hig", base, tau=t)[0]  # noqa: E731 - the --method hig preset at τ
    out += [Case("hig_tau_default", t, lambda t=t: train(small(), hig(t), hig_steps * 3, None, None))
            for t in v["tau"]]
    out += [Case("sip_eta", e, lambda e=e: train(small(), SIP(eta=e, optimizer=sgd(0.1)), steps))
            for e in v["eta"]]

    @cache
    def path(level):
        p = load(noise=level)
        xt, yt = p.sample(n_te, 2)
        return p, refs.tikhonov_path(p), xt, yt

    def alpha(level, a):
        p, (solve, smax), xt, yt = path(level)
        return {"x_err": float(np.mean(p.relative_error(solve(yt, a * smax**2), xt)))}

    for level in (0.0, 0.01) if is_linear(base.operator) else ():  # Tikhonov of a matrix
        out += [Case(f"alpha@{level:g}", a, partial(alpha, level, a)) for a in v["alpha"]]
    return out
