"""Best-α Tikhonov of a linear scene at any size, matrix-free, beside trained runs on the same test rows.

    python benchmarks/krylov_tikhonov.py wave_2d --set n=174 --set noise=0.01 [--n-test 16]
        [--iterations 200] [--runs RUN_DIR ...]

Prints the held-out relative L²(Ω) x-error of best-α Tikhonov (``argmin ‖Px − y‖²_N + α‖x‖²_M``, the α of
``ALPHA_GRID`` chosen with the test x: an oracle) from one generalized Golub–Kahan space per test row
(:func:`pdeinv.training.references.tikhonov_best_krylov`; ``converged`` is the change when half the
iterations are dropped; only α whose change is below 1 % count), its seconds, and each ``pdeinv train``
run folder's network on the same rows
(the first ``--n-test`` rows of the trainer's test stream are not the run's own unless ``--n-test 256``,
the trainer's default).
"""

import argparse
import time

import numpy as np
import torch

import pdeinv
from pdeinv.cli.commands import parse_sets
from pdeinv.training.references import tikhonov_best_krylov
from pdeinv.training.trainset import TEST_DATA, seed_stream


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("problem")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-test", type=int, default=16)
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--runs", nargs="*", default=[], help="run folders to score on the same rows")
    a = ap.parse_args()
    p = pdeinv.load_problem(a.problem, **parse_sets(a.set))
    xt, yt = p.sample(a.n_test, seed_stream(a.seed, TEST_DATA))
    label = f"{a.problem} {' '.join(a.set)} ({p.N} unknowns, {a.n_test} test rows)"
    for run in a.runs:
        _, model = pdeinv.load_run(run)
        with torch.no_grad():
            out = model(torch.as_tensor(yt, dtype=next(model.parameters()).dtype)).double().numpy()
        print(f"{label} network {run}: x_err {np.mean(p.relative_error(out, xt)):.4g}", flush=True)
    t = time.process_time()
    r = tikhonov_best_krylov(p, yt, xt, iterations=a.iterations)
    print(f"{label} best-alpha Tikhonov: x_err {r['x_err']:.4g} at rel. alpha {r['alpha_rel']:g}, "
          f"{r['iterations']} iterations (change at half: {r['converged']:.2g}), "
          f"{time.process_time() - t:.1f} CPU s")
    print("  sweep (rel. alpha: x_err, change at half): " + ", ".join(
        f"{a}: {e:.4g}, {c:.2g}" for a, (e, c) in r["sweep"].items()))


if __name__ == "__main__":
    main()
