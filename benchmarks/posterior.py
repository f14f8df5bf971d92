"""Is a trained run's posterior calibrated, exact where it can be, and sharper than the linear answer?

    OMP_NUM_THREADS=1 python benchmarks/posterior.py heat_1d --set prior=grf --set noise=0.01
        [--method sip] [--steps N] [--prior-fit {auto,0}] [--check 1000] [--draws 16384] [--seed 0]

Trains the problem as ``pdeinv.train`` does by default (the rule's preset, the prior stage, the
calibration stage), then, on ``--check`` fresh prior draws no stage saw (their own seed):

* the run's posterior: per-node coverage at 50/90/95 %, the 90 % L²(Ω) ball's coverage, SBC p-values,
  the mean 90 % interval width (:func:`pdeinv.posterior.diagnostics.report`);
* the seconds of :func:`pdeinv.posterior.predictive` (mean, std, 90 % interval) for 128 of them, the
  first call and the best of three;
* the linear-Gaussian reference, for linear physics (:func:`pdeinv.training.references.gaussian_posterior`,
  as ``pdeinv classical`` reports it): prior mean and covariance from ``--draws`` draws, the noise as
  one Gaussian (noise-free: a 1e-10 floor), the exact low-rank posterior. Printed: the median over
  nodes of (reported std / reference std), the reference's own 90 % coverage, and the width ratio at
  equal coverage: the reference's intervals are widened or narrowed by the one factor that makes them
  cover 90 % of the check rows, and the run's 90 % width is divided by theirs.

One JSON line per run, so rows from several scenes and noise levels can be collected.
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

def _equal_coverage_width(mean, std, x, level=0.9) -> tuple[float, float]:
    """(coverage of ``mean ± z std``, mean width after the one factor that makes it cover ``level``)."""
    import numpy as np
    from scipy.stats import norm

    z = norm.ppf(0.5 + level / 2)
    std = np.maximum(std, 1e-12 * std.max())  # nodes the data pin exactly (noise-free) count as rounding
    ratio = np.abs(x - mean) / std
    factor = np.quantile(ratio, level) / z
    return float(np.mean(ratio <= z)), float(np.mean(2 * z * factor * std))


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("problem")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--method", default="sip")
    p.add_argument("--steps", type=int, default=None)
    p.add_argument("--prior-fit", default="auto", choices=["auto", "0"])
    p.add_argument("--check", type=int, default=1000)
    p.add_argument("--draws", type=int, default=16384, help="prior draws of the reference's covariance")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    import numpy as np

    import pdeinv
    from pdeinv.physics.nonlinear import is_linear
    from pdeinv.posterior.diagnostics import report
    from pdeinv.posterior.predictive import forward, predictive

    overrides = dict(kv.split("=", 1) for kv in args.set)
    problem = pdeinv.load_problem(args.problem, **overrides)
    kw = {} if args.steps is None else {"steps": args.steps}
    t0 = time.perf_counter()
    result = pdeinv.train(problem, args.method, seed=args.seed, progress=False,
                          prior=None if args.prior_fit == "0" else "auto", **kw)
    wall = time.perf_counter() - t0
    cal_stage = result.metrics["stages"][-1]
    x, y = problem.sample(args.check, seed=args.seed + 2000)
    mean = forward(result.model, y)
    rows = y[:128]
    seconds = []
    for _ in range(3):  # the first call, then two more: mean, std and 90 % interval of 128 observations
        t0 = time.perf_counter()
        predictive(result.model, result.posterior, rows)
        seconds.append(time.perf_counter() - t0)
    mass = problem.disc.M
    row = {"problem": args.problem, "settings": overrides, "method": args.method, "seed": args.seed,
           "x_err": float(np.mean(problem.relative_error(mean, x))), "train_s": round(wall, 1),
           "calibration_s": round(cal_stage["seconds"], 2),
           "predict_128_s": {"first": round(seconds[0], 3), "best": round(min(seconds), 3)},
           "parameters": sum(q.numel() for q in result.model.parameters()),
           "check": report(result.posterior, mean, x, mass, seed=args.seed)}
    if is_linear(problem.operator):
        from pdeinv.training.references import gaussian_posterior

        ref, info = gaussian_posterior(problem, problem.noise, seed=args.seed + 1000, draws=args.draws)
        mu = ref.mean(y)
        coverage, width = _equal_coverage_width(mu, ref.std, x)
        row["gaussian"] = {**info,
                           "x_err": float(np.mean(problem.relative_error(mu, x))),
                           "coverage_90": coverage, "width_90_at_90": width,
                           "std_ratio_median": float(np.median(result.posterior.std / ref.std)),
                           "width_ratio": row["check"]["width_90"] / width}
    print(json.dumps(row))
    return row


if __name__ == "__main__":
    main()
