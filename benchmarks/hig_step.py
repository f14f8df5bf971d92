"""HIG's step against Adam's at the CLI defaults (issue 23: at most 2×), one thread, interleaved.

    OMP_NUM_THREADS=1 python benchmarks/hig_step.py [--scenes heat_2d,wave_2d] [--steps 40] [--repeats 3]
                                                     [--noise 0.01] [--full]

Each side trains what ``pdeinv train SCENE --method M`` trains (the preset's network, batch and data)
for ``--steps`` steps; a step's time is the median interval between consecutive steps in the second
half (HIG's first step builds what the run keeps: the operator's SVD, the rows' Gram). The sides
alternate ``--repeats`` times and the medians are compared. ``--full`` also runs each preset's whole
run once and compares ``metrics["step_s"]`` (training wall time per step, first step included).

Measured (2-core machine shared with other jobs, one thread):

* before (kept-rows route of the last session): wave_2d 2.03–2.15× (HIG 86–93 ms, Adam 40–45 ms);
* dead feature columns out of the products, modes below the float32 products' rounding left out, no
  products once the step is below the weights' resolution (:mod:`pdeinv.methods.hig.fixed`), and the
  guard's copy every 10th step for both sides: see the closing numbers in
  ``benchmarks/notes/results-history.md``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")


def step_s(problem, method: str, steps: int | None, noise: float = 0.0) -> float:
    """Median step of the second half of ``steps`` steps, or (``steps=None``) the preset run's ``step_s``."""
    import torch

    import pdeinv
    from pdeinv.io.runs import network
    from pdeinv.methods.presets import make_rule

    rule, hp = make_rule(method, problem, noise)
    spec = {"kind": "default", **({"rows_per_component": hp["rows_per_component"]}
                                  if hp.get("rows_per_component") else {})}
    torch.manual_seed(0)
    marks = {}
    n = steps or hp.get("steps", 1000)
    r = pdeinv.Trainer(problem, rule, network(problem, spec), steps=n, batch_size=hp["batch_size"],
                       eval_every=n if steps is None else 10 * n, progress=False, prior=None,
                       callbacks=[lambda rec, _m: marks.__setitem__(rec["step"], time.perf_counter())]).fit()
    if steps is None:
        return r.metrics["step_s"]
    return statistics.median(marks[k + 1] - marks[k] for k in range(n // 2, n))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="heat_2d,wave_2d")
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--noise", type=float, default=0.0, help="relative observation noise (--set noise=)")
    ap.add_argument("--full", action="store_true")
    args = ap.parse_args(argv)
    import torch

    import pdeinv

    torch.set_num_threads(1)
    for scene in args.scenes.split(","):
        problem = pdeinv.load_problem(scene, **({"noise": args.noise} if args.noise else {}))
        times = {"adam": [], "hig": []}
        for _ in range(args.repeats):
            for method in times:
                times[method].append(step_s(problem, method, args.steps, args.noise))
        a, h = statistics.median(times["adam"]), statistics.median(times["hig"])
        print(f"{scene}: {args.steps} steps x {args.repeats} (median): adam {1e3 * a:.1f} ms, "
              f"hig {1e3 * h:.1f} ms; hig / adam {h / a:.2f}", flush=True)
        if args.full:
            a, h = step_s(problem, "adam", None, args.noise), step_s(problem, "hig", None, args.noise)
            print(f"{scene}: preset runs, step_s: adam {1e3 * a:.1f} ms, hig {1e3 * h:.1f} ms; "
                  f"hig / adam {h / a:.2f}", flush=True)


if __name__ == "__main__":
    main()
