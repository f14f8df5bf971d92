"""``bench(problem, out)``: every benchmark section in one run, written to ``out/bench.json`` + PNGs.

JSON (**contract** keys marked *): ``machine``*, ``settings``, ``amortization`` (per-sample cost of the
CLI-default network against each classical solve, :mod:`.amortize`), ``ratios`` (``forward_vs_splu``*,
``adjoint_vs_forward``*, ``modal_speedup``*, ``sip_vs_gd_step``*, ``hig_step_s``*, …), ``backends``,
``forward`` (the accuracy/cost ladder), ``methods.<name>`` (``x_err``*, ``y_err``*, ``wall_s``*, …),
``reference`` (``mmse_x_err``*, ``tikhonov_best_x_err``*, ``filter_best_x_err``), ``skips.<name>``,
``notes``. A ratio that does not apply is ``null`` with a note saying why.
"""

from __future__ import annotations

import json
import math
import resource
import time
from pathlib import Path

import torch

from ..physics.nonlinear import is_linear
from ..training import references as refs
from ..training.trainset import TEST_DATA, TRAIN_DATA, seed_stream
from ..util.files import atomic_write
from ..util.outpaths import record_format
from . import amortize, backends, forward, methods, plots, skips
from .ratios import operator_ratios, step_ratios
from .timing import machine

#: run sizes: (n_train, n_test, repeats, ratio batch, sweep the hyper-parameters)
SIZES = {False: (1024, 128, 5, 64, True), True: (64, 16, 1, 8, False)}
#: training seconds per method when ``budget_s`` is not given: (full, quick); 20 s per method made
#: ``bench --quick heat_2d`` take 124 s, 1 s 27 s (idle machine, one thread)
BUDGET_S = {False: 20.0, True: 1.0}


def jsonable(obj):
    """JSON-safe: NaN/Inf become strings, so a reader sees them instead of a parse error."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    return obj


def bench(problem, out, quick: bool = False, budget_s: float | None = None, seed: int = 0,
          log=print, threads: int | None = 1) -> dict:
    """Run all sections on ``problem`` (a :class:`pdeinv.Problem`); return and write the results.

    ``budget_s``: training seconds per method (default :data:`BUDGET_S`: 20, 1 when ``quick``).
    ``threads``: torch and BLAS threads during the run (restored after; None leaves them). One by
    default: on a shared 2-core machine a second process stalls torch's 2-thread kernels at every
    barrier (Adam steps on heat_2d varied from 0.03 s to 1 s within one run).
    """
    from ..util import threads as pools

    before = torch.get_num_threads()
    if threads is not None:
        if int(threads) < 1:
            raise ValueError(f"threads={threads!r} is not allowed; expected an integer >= 1")
        pools.limit(int(threads))  # torch's and the BLAS/OpenMP pools (pdeinv.util.threads)
    try:
        return _bench(problem, out, quick, budget_s, seed, log)
    finally:
        pools.restore()
        torch.set_num_threads(before)


def _bench(problem, out, quick, budget_s, seed, log) -> dict:
    budget_s = BUDGET_S[bool(quick)] if budget_s is None else budget_s
    if not budget_s > 0:
        raise ValueError(f"budget_s={budget_s!r} is not allowed; expected a number of seconds > 0")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out={str(out)!r} is a file; expected a directory")
    out.mkdir(parents=True, exist_ok=True)
    n_train, n_test, repeats, batch, sweep = SIZES[bool(quick)]
    notes, t0 = [], time.perf_counter()
    res = {"format": record_format("bench.json"), "problem": problem.name,
           "settings": {k: str(v) for k, v in problem.settings.items()},
           "machine": machine(), "quick": bool(quick), "budget_s": budget_s, "seed": seed, "notes": notes}

    log(f"[bench] operator ratios ({problem.operator!r})")
    op_r = operator_ratios(problem, batch=batch, repeats=repeats, seed=seed)
    for key in ("forward_vs_splu", "modal_speedup"):
        if key not in op_r:
            op_r[key] = None
            why = op_r.get("modal_refused") if key == "modal_speedup" else "no implicit time stepping"
            notes.append(f"{key}: null, {why}")
    torch.manual_seed(seed)
    st = step_ratios(problem, problem.model(), batch=min(32, n_train), repeats=repeats, seed=seed)
    res["ratios"] = {**op_r, **st}

    log("[bench] backends: build, apply, memory, agreement")
    res["backends"] = backends.lines(problem, repeats=repeats, seed=seed)
    log("[bench] forward accuracy ladder")
    ns, ks = forward.default_ladder(problem, quick)
    lad = forward.ladder(problem, ns, ks, repeats=max(1, repeats - 2))
    front = forward.pareto(lad["points"])
    res["forward"] = {**lad, "pareto": front}
    if lad["points"]:
        plots.forward_pareto(lad["points"], front, out / "forward.png", f"{problem.name}: forward accuracy")

    x_tr, y_tr = problem.sample(n_train, seed_stream(seed, TRAIN_DATA))
    x_te, y_te = problem.sample(n_test, seed_stream(seed, TEST_DATA))
    if is_linear(problem.operator):
        log("[bench] references (linear MMSE, best-α Tikhonov) on the trainer's own data")
        res["reference"] = refs.references(problem, x_tr, x_te, y_te, Y_train=y_tr)
    else:  # the linear references need a matrix P; `pdeinv classical` gives nonlinear physics' oracle
        res["reference"] = None
        notes.append("reference: null, nonlinear physics (pdeinv classical: the Gauss–Newton oracle)")

    log(f"[bench] methods, {budget_s:g} s each{' after a sweep' if sweep else ''}")
    torch.manual_seed(seed)
    res["methods"] = methods.compare(problem, budget_s, seed=seed, n_train=n_train, n_test=n_test,
                                     sweep=sweep, eval_every=10 if not quick else 2)
    plots.methods(res["methods"], res["reference"], out / "methods.png",
                  f"{problem.name}: {budget_s:g} s per method")
    models = {name: m.pop("model", None) for name, m in res["methods"].items()}

    _linear_parts(res, problem, models.get("sip_cli_default"), (x_te, y_te), st, op_r, repeats, seed, log)
    res["total_s"] = time.perf_counter() - t0
    res["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB
    text = json.dumps(jsonable(res), indent=2, default=str).encode()
    atomic_write(out / "bench.json", lambda fh: fh.write(text))  # a kill never leaves half a file
    return res


def _linear_parts(res, problem, net, test, st, op_r, repeats, seed, log) -> None:
    """``res["amortization"]`` (the trained ``net`` against classical solves per sample) and
    ``res["skips"]``; both ``None`` on nonlinear physics, whose classical solves and adjoint skips are not
    those of a matrix ``P``."""
    if not is_linear(problem.operator):
        res["notes"].append("amortization, skips: null, nonlinear physics (the classical solves and the "
                            "adjoint skips measured there are those of a linear P)")
        res["amortization"] = res["skips"] = None
        return
    log("[bench] amortization (trained network vs classical solves, per sample)")
    wall_s = res["methods"]["sip_cli_default"]["wall_s"]
    res["amortization"] = (None if net is None else  # None: the preset's run ended in NaN
                           amortize.amortization(problem, net, wall_s, *test, repeats=repeats))
    log("[bench] skips")
    res["skips"] = skips.measure(problem, st, repeats=repeats, seed=seed, modal_info=op_r)


def summary(res: dict) -> str:
    """A few lines for the terminal."""
    r, ref = res["ratios"], res["reference"]
    fmt = lambda v: "n/a" if v is None else f"{v:.3g}"  # noqa: E731
    keys = ("forward_vs_splu", "adjoint_vs_forward", "modal_speedup", "sip_vs_gd_step", "hig_step_s")
    lines = [f"{res['problem']}: " + ", ".join(f"{k} {fmt(r.get(k))}" for k in keys),
             "reference: none (nonlinear physics)" if ref is None else
             f"reference: MMSE x_err {ref['mmse_x_err']:.4f}, best-α Tikhonov x_err "
             f"{ref['tikhonov_best_x_err']:.4f}, best spectral filter x_err {ref['filter_best_x_err']:.4f}"]
    for name, b in (res.get("backends") or {}).get("lines", {}).items():
        ok = b["outcome"] == "ok"
        build = "build n/a (none needed)" if b["build_s"] is None else f"build {fmt(b['build_s'])} s"
        text = (f"{build}  apply {b['apply_s'] * 1e3:.2f} ms  {b['memory_mb']:.1f} MB  "
                f"agreement {b['agreement']:.1e}") if ok else b["outcome"]
        lines.append(f"  backend {name:6s} {text}")
    for name, m in res["methods"].items():
        lines.append(f"  {name:22s} x_err {m['x_err']:.4f}  y_err {m['y_err']:.4f}  "
                     f"wall {fmt(m['wall_s'])} s  steps {m.get('steps')} ({m.get('stopped_by')})")
    for name, row in ((res.get("amortization") or {}).get("rows") or {}).items():
        lines.append(f"  amortization {name:15s} {row['s_per_sample'] * 1e3:.3f} ms/sample  x_err "
                     f"{row['x_err']:.4f}  " + _break_even(name, row["break_even_samples"]))
    return "\n".join(lines)


def _break_even(name: str, samples) -> str:
    if name == "network":
        return ""
    return ("never breaks even (the network is not faster per sample)" if samples is None
            else f"break-even {samples} samples")
