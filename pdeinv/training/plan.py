"""What a run will do and what it will hold: its stages after the rule's, the plan that lists them
before anything is built (:func:`plan`, :meth:`Plan.explain`), and the memory that plan prices
(:func:`run_bytes`, :func:`check_training`).

**Stages.** A run is the rule's stage (the trainer's loop: GD, SIP, HIG, … train the network through
the physics) followed, where the network has a part fitted on the prior
(:class:`pdeinv.nets.refine.PriorFitted`) and a prior is available (the scene's sampler, or the ``x`` rows
of the user's file), by the :class:`PriorStage`: its correction is fitted on prior draws and its
data-consistency layer gives the observations back (:mod:`pdeinv.nets.consistency`). Every budget is a
count (draws, steps, multiply-adds); each stage reports its own held-out x- and y-errors and seconds in
``metrics["stages"]``.

**The plan.** One chooser for ``pdeinv train`` and Python alike (lineax's ``AutoLinearSolver`` is the
model: a chooser you can ask). It reads what the problem already decided (the operator's backend and why,
:meth:`pdeinv.physics.propagator.Propagator.compile`; the local inverse), the rule's preset
(:mod:`pdeinv.methods.presets`), which network the problem gets (:mod:`pdeinv.nets.defaults`) and the
stages with their counts, and prices that same plan in memory with the guard's own estimate.

**Memory.** What a training run will hold at its peak, by part (:func:`run_bytes`), and the guard that
refuses it before any part is allocated (:func:`check_training`; the budget and the primitive checks:
:mod:`pdeinv.util.memory`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from ..inverse import TikhonovCG
from ..methods.sip import CHUNK_ENTRIES
from ..nets import network_size
from ..nets.refine import PriorFit, PriorFitted, Refined
from ..posterior.stage import stage as calibration_stage
from ..util.memory import GB, HIG_JACOBIAN_GB, check
from .trainset import N_TRAIN, prior_rows, test_count

#: prior draws for the stage's decision, before any fitting (their own seed stream)
PILOT = 64

#: a base whose relative error on the pilot draws is below this leaves the prior too little to add: the
#: float32 corrections were never kept below it (noise-free heat_2d 0.0016, heat_plate 0.0020, heat_1d
#: 0.0040, wave_2d 5e-9, each after 6–180 s of fitting), and they gain 2–4× where the base is above it
NEGLIGIBLE = 0.01

#: prior draws of a default stage: at most this many field entries (x and y, float64: ~320 MB) and
#: :data:`MOST_DRAWS` rows, never fewer than :data:`FEWEST_DRAWS` or than :data:`ENTRIES_4K` allows
ENTRIES, MOST_DRAWS, FEWEST_DRAWS = 20_000_000, 65_536, 256
#: at 10⁴–10⁵ unknowns one U-Net step takes seconds and a fit sees a few thousand draws at most
ENTRIES_4K = 50_000_000


#: multiply-adds a default stage's fit may spend (forward and backward, ~3× a forward pass per draw), a
#: count, the same on every machine, sized so that the scenes' defaults end within 2 min on one core:
#: ~250 U-Net steps of 32 draws on heat_boxes' 63×63 grid (held-out 0.047; twice as many reached 0.037–0.044)
#: or ~2 900 steps of sine_gordon_2d's dense MLP (~25 ms each: dense products run slower per multiply-add)
FIT_MACS = 2.25e12


def step_count(problem, kind: str, batch: int, n_train: int, fit: PriorFit) -> int:
    """The stage's fitting steps: ``fit.steps`` if set, else the fewer of ``fit``'s passes over the
    ``n_train`` training draws and what :data:`FIT_MACS` buys at :func:`~pdeinv.nets.corrections.
    correction_macs` per draw."""
    from ..nets.corrections import correction_macs
    from ..physics.capabilities import modal_basis

    if fit.steps is not None:
        return fit.steps
    macs = correction_macs(kind, problem.N, problem.operator.n_out, problem.points.shape[0],
                           modal_basis(problem.operator) is not None)
    return int(max(1, min(fit.step_count(n_train, batch), FIT_MACS // (3 * macs * batch))))


def draw_count(N: int, flops: float | None = None) -> int:
    """The default stage's prior draws for ``N`` unknowns: ``min(65 536, 2·10⁷/N)``, at least
    ``min(4 096, 5·10⁷/N)`` and 256 (heat_boxes 64²: 5 039; heat_1d: 65 536; 30 k unknowns: 1 670), and at
    most what :data:`DRAW_FLOPS` buys at ``flops`` per draw (the operator's ``forward_flops()``; None: not
    priced), never fewer than 256. A dense correction on 4 096 sine_gordon_1d draws early-stopped at
    0.094, on 16 384 it reached 0.064."""
    N = max(int(N), 1)
    n = int(max(FEWEST_DRAWS, min(4096, ENTRIES_4K // N), min(MOST_DRAWS, ENTRIES // N)))
    if flops is not None and flops > 0:
        n = min(n, max(FEWEST_DRAWS, int(DRAW_FLOPS // flops)))
    return n


#: flops the default stage's prior draws may spend by the operator's cost model (a count, the same on
#: every machine): ~10 k allen_cahn_2d draws (9.6e6 each, ~30 s of chord solves on one core); the
#: linear scenes' compiled draws cost 10³–10⁷ each and stay uncapped
DRAW_FLOPS = 1e11


@dataclass(frozen=True)
class PriorStage:
    """Fit a network's prior part on ``draws`` prior pairs (``None``: :func:`draw_count`) with ``fit``'s
    settings (:class:`~pdeinv.nets.refine.PriorFit`, seeded with the run's seed; its steps, when not set,
    :func:`step_count`). Decided against before it fits (:meth:`why_not`) when the data carry no prior, or
    when the rule's estimate is already within :data:`NEGLIGIBLE` of :data:`PILOT` prior draws."""

    fit: PriorFit = field(default_factory=PriorFit)
    draws: int | None = None
    name: str = "prior"

    def __post_init__(self):
        from .._checks import label

        label(self.name, "PriorStage(name)")
        if not isinstance(self.fit, PriorFit):
            raise TypeError(f"PriorStage(fit={self.fit!r}) is not allowed; expected a "
                            "pdeinv.nets.refine.PriorFit")
        if self.draws is not None and (isinstance(self.draws, bool) or not isinstance(self.draws, int)
                                       or self.draws < 2):
            raise ValueError(f"PriorStage(draws={self.draws!r}) is not allowed; expected an integer >= 2 or "
                             "None (the default count)")

    def applies(self, model) -> bool:
        return isinstance(model, PriorFitted)

    def draw_count(self, problem) -> int:
        if self.draws is not None:
            return self.draws
        return draw_count(problem.N, problem.operator.forward_flops())

    def planned(self, problem, kind: str, own=None) -> dict:
        """What the stage will do for a correction of ``kind`` (:func:`pdeinv.nets.defaults.correction_kind`),
        before anything is built (:func:`pdeinv.training.plan.plan`)."""
        from ..nets.corrections import fit_batch
        from ..physics.capabilities import modal_basis

        if own is not None and own.x is None:
            return {"name": self.name, "skipped": "no prior: the data file has no x"}
        n = len(own.x) if own is not None else self.draw_count(problem)
        batch = self.fit.batch or fit_batch(kind, problem.N, problem.points.shape[0])
        n_train = n - max(1, round(self.fit.held_out * n))
        steps = step_count(problem, kind, batch, n_train, self.fit)
        source = ("the data file's x" if own is not None
                  else problem.settings.get("prior", "the scene's sampler"))
        names = {"grid": "a U-Net on the grid", "dense": "a dense MLP",
                 "span": "an MLP in the decoder's span"}
        return {"name": self.name, "draws": n, "max_steps": steps,
                "batch": batch,
                "correction": names.get(kind, kind), "prior": source,
                "consistency": modal_basis(problem.operator) is not None}

    def why_not(self, problem, model, own, seed: int, relative_error, log=None) -> str | None:
        """Why the stage cannot help, from :data:`PILOT` prior draws (no fitting), or ``None``;
        ``log(line)``, if given, hears how long the stage's draws will take at the pilot draws' pace (a
        print: nothing is decided by it)."""
        t0 = time.perf_counter()
        pilot, source = prior_rows(problem, own, PILOT, seed, stream=1)
        if pilot is None:
            return f"no prior: {source}"
        pace = (time.perf_counter() - t0) / PILOT
        x, y = pilot[0][:PILOT], pilot[1][:PILOT]
        dtype = next(model.parameters()).dtype
        with torch.no_grad():
            xb = model(torch.as_tensor(y, dtype=dtype)).double().numpy()
        err = float(np.mean(relative_error(xb, x)))
        if err <= NEGLIGIBLE:
            return (f"the rule's estimate is within {err:.2g} of {len(x)} prior draws (relative L2 error, at "
                    f"most {NEGLIGIBLE:g}): too little is left for the prior")
        if log is not None and own is None:
            n = self.draw_count(problem)
            log(f"prior stage: {PILOT} pilot draws took {pace * PILOT:.2g} s: the stage's {n} draws will "
                f"take at most ~{pace * n:.0f} s (large batches go faster), then the fit")
        return None

    def run(self, problem, model, own, seed: int, log=None) -> dict:
        """Draw, fit, and say what was done (``kept``, ``draws``, ``steps``, held-out errors, ``prior``);
        ``log(line)``, if given, hears what the stage is doing and its estimate of what is left."""
        t0 = time.perf_counter()
        if log is not None and own is None:
            log(f"prior stage: drawing {self.draw_count(problem)} prior pairs (x, y = P x)")
        draws, source = prior_rows(problem, own, self.draw_count(problem), seed)
        if draws is None:
            return {"kept": False, "skipped": f"no prior: {source}", "prior": source}
        fit = replace(self.fit, seed=seed)
        if isinstance(model, Refined):  # a user's own PriorFitted network counts its own steps
            n = len(draws[0])
            batch = self.fit.batch or model.correction.fit_batch
            held = max(1, round(self.fit.held_out * n))
            fit = replace(fit, steps=step_count(problem, model.correction_kind, batch, n - held, self.fit))
        if log is not None:
            count = f"at most {fit.steps} steps" if fit.steps is not None else "its own count of steps"
            log(f"prior stage: {source} ready after {time.perf_counter() - t0:.0f} s; fitting the correction "
                f"for {count}")
        info = fit.fit(model, *draws, problem.relative_error, log)
        return {**info, "prior": source, "seconds": time.perf_counter() - t0}


@dataclass(frozen=True)
class Plan:
    """A run's decisions and their reasons (:func:`plan`); :meth:`explain` prints them."""

    problem: dict
    rule: dict
    network: dict
    stages: list[dict]
    memory: dict = field(default_factory=dict)

    def explain(self) -> str:
        p, r, net = self.problem, self.rule, self.network
        lines = [f"problem   {p['name']}: {p['unknowns']} unknowns, {p['observations']} observations, "
                 f"{'linear' if p['linear'] else 'nonlinear'} physics, noise {p['noise']:g}",
                 f"backend   {p['backend']}",
                 f"inverse   {p['inverse']}",
                 *([f"units     the data divided by {p['units']:g} for training, answers in the data's units "
                    "(pdeinv.problem.units)"] if p.get("units", 1.0) != 1.0 else []),
                 f"rule      {r['name']}: {r['steps']} steps of {r['batch']} rows on {r['n_train']} training "
                 f"observations ({', '.join(f'{k}={v}' for k, v in r['settings'].items())})"
                 + (f"; route {r['route']}" if r.get("route") else ""),
                 f"network   {net['kind']}: {net['params']:,} trained parameters, {net['buffers']:,} fixed "
                 f"numbers ({net['why']})"]
        for i, st in enumerate(self.stages, 1):
            lines.append(f"stage {i}   {_stage_text(st)}")
        if self.memory:
            total = sum(self.memory.values())
            ranked = sorted(self.memory.items(), key=lambda kv: -kv[1])
            parts = ", ".join(f"{k} {v / GB:.3g}" for k, v in ranked)
            lines.append(f"memory    {total / GB:.3g} GB at the peak ({parts})")
        return "\n".join(lines)

    def summary(self) -> str:
        """The stages and their counts in one line (what a run prints before it starts)."""
        parts = [f"{self.rule['name']} {self.rule['steps']} steps of {self.rule['batch']} rows"]
        for st in self.stages[1:]:
            if st.get("skipped"):
                continue
            if st["name"] == "prior":
                parts.append(f"prior (unless the rule is within {NEGLIGIBLE:g}): at most {st['max_steps']} "
                             f"steps on {st['draws']} draws")
            else:
                parts.append(f"{st['name']}: {st['rows']} held-out {'rows' if st.get('own') else 'draws'}")
        return "plan: " + " -> ".join(parts)

    def as_dict(self) -> dict:
        return {"problem": self.problem, "rule": self.rule, "network": self.network, "stages": self.stages,
                "memory_bytes": self.memory}


def _stage_text(st: dict) -> str:
    if st["name"] == "calibration":
        if st.get("skipped"):
            return f"calibration: none ({st['skipped']})"
        rows = (f"{st['rows']} held-out rows of the data file" if st.get("own") else
                f"{st['rows']} held-out draws of the prior ({st['prior']})")
        return (f"calibration: the network's residuals on {rows} give its posterior: per-node scale from "
                "half, split-conformal quantiles from the other half (std, intervals at any level, samples: "
                "posterior.npz)")
    if st["name"] == "prior":
        if st.get("skipped"):
            return f"prior: none ({st['skipped']})"
        dc = ("then the data-consistency layer in the modes the data cannot decide (the rule's estimate kept "
              "where they resolve it)" if st["consistency"]
              else "no data-consistency layer (the operator has no spectral basis)")
        return (f"prior: unless the rule's estimate is within {NEGLIGIBLE:g} of {PILOT} pilot draws, "
                f"{st['correction']} fitted on {st['draws']} prior draws ({st['prior']}), at most "
                f"{st['max_steps']} steps of {st['batch']}, kept only if it lowers the held-out error; {dc}")
    data = " on new prior draws each step, x in no loss" if st.get("fresh") else ""
    return f"{st['name']}: the rule trains the network through the physics ({st['steps']} steps{data})"


#: the network kinds ``plan(net=...)`` prices by name (``pdeinv train --net``; ``hidden=`` is the MLP)
NETS = ("default", "linear", "whitened", "reduced", "modal", "unet")


def _checked(net, hidden, n_train, steps, batch_size, own, n_test, prior, fresh=False) -> tuple:
    """:func:`plan`'s arguments checked as :class:`~pdeinv.Trainer` checks them (the same messages), before
    anything is built: ``(hidden, steps, batch_size, prior)``, ``"preset"`` read as ``None``."""
    from numbers import Integral

    from .._checks import choice, count
    from . import arguments
    from .data import OwnData

    choice(net, "net", NETS)
    if hidden is not None:
        widths = "expected a list of integer widths >= 1, e.g. [64, 64] (the CLI's --hidden 64,64)"
        if isinstance(hidden, (str, bytes)) or not isinstance(hidden, (list, tuple)):
            raise TypeError(f"hidden={arguments._short(hidden)} is {type(hidden).__name__}; {widths}")
        if not hidden or any(isinstance(w, bool) or not isinstance(w, Integral) or w < 1 for w in hidden):
            raise ValueError(f"hidden={arguments._short(hidden)} is not allowed; {widths}")
        if net != "default":
            raise ValueError(f"net={net!r} and hidden={list(hidden)} choose two networks (hidden is the "
                             "MLP's widths): drop one of them")
        hidden = tuple(hidden)
    if own is not None and not isinstance(own, OwnData):
        raise TypeError(f"own={arguments._short(own)} is {arguments._kind(own)}; expected None or the user's "
                        "rows: pdeinv.training.data.own_data(problem, y, x, n_test, 0, False, stage)")
    preset = lambda v: v is None or (isinstance(v, str) and v == "preset")  # noqa: E731
    steps = None if preset(steps) else count(steps, "steps")
    count(n_test, "n_test")
    n_train = count(n_train, "n_train", minimum=2)  # the CLI's --n-train range: whitening
    batch_size = None if preset(batch_size) else count(batch_size, "batch_size")
    big = batch_size is not None and batch_size > n_train and fresh is not True  # fresh: new rows each step
    if big and own is None:
        raise ValueError(f"batch_size={batch_size} is larger than n_train={n_train}; expected batch_size <= "
                         f"{n_train}")
    if big:
        raise ValueError(f"batch_size={batch_size} (--batch-size) is larger than the {n_train} training rows "
                         f"of data (its rows less n_test={n_test} (--n-test) and the other held-out rows); "
                         f"expected at most {n_train}")
    return hidden, steps, batch_size, arguments.prior(prior)


def prior_part(problem, net: str = "default", hidden=None) -> bool:
    """Whether the network ``--net net`` (``--hidden``: an MLP) of ``problem`` has a part the prior stage
    fits (:class:`~pdeinv.nets.refine.Refined`): the default network and the U-Net, where the problem has a
    correction for its mesh and no network of its own."""
    from ..nets.defaults import correction_kind

    return (not hidden and net in ("default", "unet") and problem.model_factory is None
            and correction_kind(problem) is not None)


def plan(problem, rule: str = "sip", *, net: str = "default", hidden=None, prior="auto",
         n_train: int = N_TRAIN, steps: int | None = None, batch_size: int | None = None, own=None,
         n_test: int | None = None, fresh: bool = False, calibration="auto", **settings) -> Plan:
    """The plan of ``Trainer(problem, rule, ...)`` / ``pdeinv train`` with these arguments (``problem`` a
    :class:`~pdeinv.Problem`, a name or a module path; ``rule`` a method name; ``settings`` the rule's, as
    :func:`pdeinv.methods.presets.make_rule` takes them; ``own``: a
    :class:`pdeinv.training.data.OwnData`, the user's rows). Builds nothing but the problem and the
    rule."""
    from ..methods.presets import make_rule, run_defaults
    from ..nets import network_size
    from ..nets.defaults import correction_kind
    from ..physics.nonlinear import is_linear
    from ..problem import Problem, load_problem

    n_test = test_count(n_test, own is not None)
    hidden, steps, batch_size, prior = _checked(net, hidden, n_train, steps, batch_size, own, n_test, prior,
                                               fresh)
    if not isinstance(problem, Problem):  # a name or a module path, as Trainer takes it
        problem = load_problem(problem)
    from ..nets import NONLINEAR_KINDS

    linear_net = not hidden and net not in NONLINEAR_KINDS
    rule_obj, hp = make_rule(rule, problem, problem.noise, linear_net=linear_net, hidden=hidden, **settings)
    preset = run_defaults(rule_obj, None, problem)
    steps = steps if steps is not None else hp.get("steps") or preset["steps"]
    batch = batch_size or hp.get("batch_size") or n_train
    kind = "mlp" if hidden else net
    size = network_size(problem, kind, hidden, hp.get("rows_per_component"))
    op = problem.operator
    info = {"name": problem.name, "unknowns": problem.N, "observations": op.n_out, "linear": is_linear(op),
            "noise": float(problem.noise or 0.0),
            "backend": getattr(op, "choice", None) or type(op).__name__,
            "inverse": repr(problem.inverse_simulator), **({"units": own.units} if own is not None else {})}
    stages = [{"name": rule_obj.name, "steps": steps, "batch": batch, "fresh": bool(fresh)}]
    refined = prior_part(problem, net, hidden)
    prior_draws = 0
    if refined and prior is not None:
        st = prior.planned(problem, correction_kind(problem), own)
        stages.append(st)
        prior_draws = 0 if st.get("skipped") else st["draws"]
    calibration = calibration_stage(calibration)
    if calibration is not None:
        stages.append(calibration.planned(problem, own))
    memory = run_bytes(problem, n_train, n_test, batch, hidden, kind if kind != "mlp" else "default",
                       rule, 128, prior_draws, hp.get("optimizer") or "adam", hp.get("rows_per_component"))
    why = ("the MLP of --hidden" if hidden else
           "a U-Net on the observations and the physics' linear estimate, trained by the rule end to end"
           + (", plus a nonlinear correction and a data-consistency layer for the prior stage" if refined
              else "") if kind == "unet" else
           "the problem's default: a linear estimate trained by the rule" + (
               ", plus a nonlinear correction and a data-consistency layer for the prior stage" if refined
               else ""))
    rule_info = {"name": rule_obj.name, "steps": steps, "batch": batch, "n_train": n_train,
                 "settings": {k: v for k, v in hp.items() if v is not None and k not in ("steps",)}}
    if rule_obj.name == "hig":
        rule_info["route"] = hig_route(problem, batch, int(size["params"]), linear_net, bool(hidden))
    return Plan(info, rule_info,
                {"kind": kind, "params": int(size["params"]), "buffers": int(size["buffers"]), "why": why},
                stages, memory)


def hig_route(problem, batch: int, params: int, linear: bool, dense_net: bool) -> str:
    """Which route HIG's ``"auto"`` takes (:data:`pdeinv.methods.hig.routes.ROUTES`), from the sizes alone:
    the exact Kronecker step on a network linear in its parameters; else the dense Jacobian of ``batch ·
    rank`` rows where it fits :data:`~pdeinv.util.memory.HIG_JACOBIAN_GB`, else the last layer's exact step
    (a dense MLP) or the matrix-free randomized route."""
    from ..methods.hig.routes import SVD
    from ..methods.hig.rule import HIG
    from ..physics.capabilities import modal_basis

    if linear:
        return "Kronecker: the exact step, no Jacobian formed"
    basis = modal_basis(problem.operator)
    per_sample = min(problem.operator.n_out, len(basis.g)) if basis is not None else problem.operator.n_out
    rows = batch * per_sample
    if SVD.bytes_per_entry * rows * params <= HIG_JACOBIAN_GB * 2**30:
        return f"dense Jacobian {rows} x {params}, decomposed"
    if dense_net:
        return f"the last layer's exact step (the Jacobian {rows} x {params} exceeds {HIG_JACOBIAN_GB:g} GB)"
    products = (2 + 2 * HIG.power_iters) * HIG.probes  # J Ω, q times J Jᵀ Q, Jᵀ Q
    return (f"matrix-free: rank-{HIG.probes} randomized SVD from Jacobian products, {products} "
            f"passes of the batch through network and physics per step (the Jacobian {rows} x {params} "
            f"exceeds {HIG_JACOBIAN_GB:g} GB)")


#: copies per trained parameter in its dtype: value, gradient and, with Adam, two moments
STATE_COPIES = {"adam": 4, "sgd": 2}


def run_bytes(problem, n_train: int, n_test: int, batch: int, hidden=None, net: str = "default",
              method: str | None = None, n_val: int = 0, prior_draws: int = 0,
              optimizer: str = "adam", rows_per_component=None) -> dict:
    """What a training run will hold at its peak, by part (bytes; each an upper bound to a small factor):

    * ``data``: training, test and stopping rows (``x``, ``y`` in float64, ``y`` again in the network's
      dtype) and the prior fit's draws (``x``, ``y``), all alive at the prior fit;
    * ``network``: the network ``--net`` / ``--hidden`` builds (:func:`pdeinv.nets.network_size`; the
      default's decoder-or-fallback counted as the larger): its buffers, and per trained parameter its
      value, gradient and, with Adam (``optimizer``; GD and Adam rules: Adam), two moments;
    * ``batch``: one batch through network and physics: the output and its gradient at the widest layer,
      and ``x``, ``y``, the residual and the local inverse's result (float64); for SIP one chunk of rows
      (:data:`pdeinv.methods.sip.CHUNK_ENTRIES`);
    * ``set-up``: the larger of what building the network needs on top (the prior decoder's draws and Gram
      matrix) and the whitening fit's SVD of the training observations (three ``(n, m)`` arrays): they
      come one after the other and are freed before training;
    * ``inverse``: the generic Tikhonov CG inverse (:class:`pdeinv.inverse.TikhonovCG`, where the operator
      has no spectral basis): its ten ``(B, N)`` work arrays and its bounded reorthogonalization history;
    * ``HIG Jacobian``: HIG's stacked Jacobian on a network that is not linear in its parameters, at most
      its budget (:data:`HIG_JACOBIAN_GB`; HIG refuses or goes matrix-free above it).

    An upper bound (heat_2d at n=256: ~1.5× the peak RSS, benchmarks/notes/scaling.md).
    """
    m, n = problem.operator.n_out, problem.operator.n_in
    size = network_size(problem, "mlp" if hidden else net, hidden, rows_per_component)
    d = size["dtype_bytes"]
    copies = STATE_COPIES["sgd" if method == "sip" and optimizer == "sgd" else "adam"]
    rows = min(batch, max(1, CHUNK_ENTRIES // max(m, n, 1))) if method in (None, "sip") else batch
    parts = {
        "data": (n_train + n_test + n_val) * (8 * (m + n) + d * m) + prior_draws * 8 * (m + n),
        "network": copies * d * size["params"] + d * size["buffers"],
        "batch": 2 * d * rows * size["widest"] + 8 * rows * (n + 2 * m),
        "set-up": max(size["build"], 3 * 8 * n_train * m),
    }
    inverse = problem.inverse_simulator
    if method in (None, "sip") and isinstance(inverse, TikhonovCG):
        parts["inverse"] = inverse.memory_bytes(rows)
    from ..nets import NONLINEAR_KINDS

    linear_net = not hidden and problem.model_factory is None and net not in NONLINEAR_KINDS
    if method == "hig" and not linear_net:  # the default networks take the Kronecker route: no J
        parts["HIG Jacobian"] = min(8.0 * batch * m * size["params"], HIG_JACOBIAN_GB * 2**30)
    return parts


def check_training(problem, n_train: int, n_test: int, batch: int, hidden=None, net: str = "default",
                   method: str | None = None, n_val: int = 0, prior_draws: int = 0,
                   optimizer: str = "adam", rows_per_component=None) -> dict:
    """Refuse a training run whose parts (:func:`run_bytes`) would not fit, before any of them is
    allocated, with the estimate, its largest parts and the budget in one line; returns the parts."""
    parts = run_bytes(problem, n_train, n_test, batch, hidden, net, method, n_val, prior_draws, optimizer,
                      rows_per_component)
    m, n = problem.operator.n_out, problem.operator.n_in
    top = sorted(parts.items(), key=lambda kv: -kv[1])[:3]
    what = ", ".join(f"{k} {v / GB:.3g}" for k, v in top)
    params = network_size(problem, "mlp" if hidden else net, hidden, rows_per_component)["params"]
    size_net = f"--hidden {','.join(map(str, hidden))}" if hidden else f"--net {net}"
    check(sum(parts.values()), f"training {problem.name} ({n_train} + {n_test} samples of {m} observations "
                               f"and {n} unknowns, {size_net}: a network of {params:.3g} parameters; "
                               f"GB: {what})",
          "use a smaller --n-train / --n-test or --batch-size, another --net or --hidden, or a coarser mesh")
    return parts
