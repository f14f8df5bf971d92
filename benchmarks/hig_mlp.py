"""HIG on an MLP (``pdeinv train SCENE --method hig --hidden W,W``): today's route and the last-layer route.

    OMP_NUM_THREADS=1 python benchmarks/hig_mlp.py [--scenes heat_1d heat_2d wave_2d] [--hidden 64,64]
        [--steps 100] [--batch 32] [--equal-time]

Per scene, the same MLP (``pdeinv.MLP``, seed 0, the CLI's ``--hidden`` network) is trained by the CLI's
HIG preset (η 1, τ 1e-6) on the same 1024 training observations in the same batch order, once per
route, the routes interleaved in one process on one thread:

* ``auto``: today's choice for a network not linear in θ (the dense Jacobian with the Gram or SVD,
  or matrix-free when the dense Jacobian exceeds ``max_jacobian_gb``);
* ``last_layer``: the last layer's exact step, hidden layers fixed (:mod:`pdeinv.methods.hig.layers`);
* with ``--equal-time``: ``last_layer`` again with the first route's wall time as its time budget
  (row ``last=t``).

``--routes randomized last_layer`` measures what ``auto`` took before ``last_layer`` existed where the
dense Jacobian does not fit (the 2-D scenes).

A step's time is the median interval between consecutive steps 2 … steps−1 (the first step builds
the operator's SVD); the x-error is the trainer's final test x-error (mean relative L²(Ω), 128 test
pairs). Prints one row per run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")


def run(problem, hidden, route: str, steps: int | None, batch: int, budget: float | None = None) -> dict:
    import dataclasses

    import torch

    import pdeinv
    from pdeinv.io.runs import network
    from pdeinv.methods.presets import make_rule

    rule, _ = make_rule("hig", problem, hidden=hidden)
    rule = dataclasses.replace(rule, route=route)
    torch.manual_seed(0)
    model = network(problem, {"kind": "mlp", "hidden": list(hidden)})
    marks, routes = {}, set()

    def clock(record, _model):
        marks[record["step"]] = time.perf_counter()
        routes.add(record.get("route"))

    start = time.perf_counter()
    result = pdeinv.Trainer(problem, rule, model, steps=steps, time_budget=budget, batch_size=batch,
                            eval_every=10**9, callbacks=[clock], progress=False).fit()
    wall = time.perf_counter() - start
    done = max(marks)
    gaps = [marks[k + 1] - marks[k] for k in range(2, done) if k + 1 in marks]
    return {"route": route, "taken": "/".join(sorted(map(str, routes))), "steps": done,
            "ms": 1e3 * statistics.median(gaps) if gaps else float("nan"), "wall": wall,
            "x_err": result.metrics.get("x_err")}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["heat_1d", "heat_2d", "wave_2d"])
    parser.add_argument("--hidden", default="64,64")
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--routes", nargs="+", default=["auto", "last_layer"])
    parser.add_argument("--equal-time", action="store_true")
    args = parser.parse_args(argv)

    from pdeinv.util.threads import limit

    limit(1)
    import pdeinv

    hidden = tuple(int(w) for w in args.hidden.split(","))
    print(f"{'scene':<10} {'hidden':<9} {'batch':>5} {'route':<10} {'taken':<12} {'steps':>5} "
          f"{'ms/step':>9} {'wall s':>8} {'x-error':>9}", flush=True)
    for scene in args.scenes:
        problem = pdeinv.load_problem(scene)
        walls = {}
        for route in args.routes:
            row = run(problem, hidden, route, args.steps, args.batch)
            walls[route] = row["wall"]
            show(scene, hidden, args.batch, row)
        if args.equal_time:
            row = run(problem, hidden, "last_layer", None, args.batch, budget=walls[args.routes[0]])
            show(scene, hidden, args.batch, {**row, "route": "last=t"})


def show(scene, hidden, batch, row) -> None:
    print(f"{scene:<10} {','.join(map(str, hidden)):<9} {batch:>5} {row['route']:<10} {row['taken']:<12} "
          f"{row['steps']:>5} {row['ms']:>9.1f} {row['wall']:>8.1f} {row['x_err']:>9.4f}", flush=True)


if __name__ == "__main__":
    main()
