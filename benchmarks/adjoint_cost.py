"""The cost of a nonlinear scene's exact adjoint against its forward map (issue 34's "adjoint ≤ 3 × forward").

    OMP_NUM_THREADS=1 python benchmarks/adjoint_cost.py allen_cahn_1d [--set KEY=VALUE] [--batch 1024]
        [--repeats 3]

Times ``problem.operator.forward(X)`` and ``problem.operator.vjp(X', R)`` *from scratch* (``X'`` a different
point, so no checkpoints of the forward run are reused: the checkpoint run, the segment recomputation and
one transposed tangent solve per step) on ``batch`` prior draws, alternating ``--repeats`` times in one
process; prints each time, and the ratio ``vjp / forward`` of the minima and of the medians.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import pdeinv
from pdeinv.cli.commands import parse_sets


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("problem")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    p = pdeinv.load_problem(a.problem, **parse_sets(a.set))
    op = p.operator
    x, _ = p.sample(a.batch, seed=1)
    rng = np.random.default_rng(0)
    R = rng.standard_normal((a.batch, op.n_out))
    forward, vjp = [], []
    for _ in range(a.repeats):
        X = x + 1e-3 * rng.standard_normal(x.shape)
        t0 = time.perf_counter()
        op.forward(X)
        forward.append(time.perf_counter() - t0)
        X = x + 1e-3 * rng.standard_normal(x.shape)  # another point: the vjp pays its own checkpoint run
        t0 = time.perf_counter()
        op.vjp(X, R)
        vjp.append(time.perf_counter() - t0)
    print(f"{a.problem} {' '.join(a.set)} ({p.N} unknowns, batch {a.batch}): forward "
          f"{[round(t, 3) for t in forward]} s, vjp {[round(t, 3) for t in vjp]} s; vjp / forward "
          f"{min(vjp) / min(forward):.2f} (minima), {np.median(vjp) / np.median(forward):.2f} (medians)")


if __name__ == "__main__":
    main()
