"""The cost of a nonlinear scene's exact adjoint against its forward map (issue 34's "adjoint ≤ 3 × forward").

    OMP_NUM_THREADS=1 python benchmarks/adjoint_cost.py allen_cahn_1d [--set KEY=VALUE] [--batch 1024]
        [--repeats 3]

Times, on ``batch`` prior draws, alternating ``--repeats`` times in one process:

* ``problem.operator.forward(X)``;
* ``problem.operator.vjp(X', R)`` *from scratch* (``X'`` a different point, so no checkpoints of a forward
  run are reused: the checkpoint run, the segment recomputation and one transposed tangent solve per step);
* the *adjoint after the forward*: ``vjp(X, R)`` right after ``forward(X)`` at the same ``X``, what the torch
  bridge does in training (the forward's checkpoints are reused: the reverse sweep alone, the usual meaning
  of "the adjoint's cost", as in dolfin-adjoint, where the forward run records what the adjoint needs).

Prints each time, and the ratios to the forward of the minima and of the medians.
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
    forward, vjp, after = [], [], []
    for _ in range(a.repeats):
        X = x + 1e-3 * rng.standard_normal(x.shape)
        forward.append(_seconds(op.forward, X))
        after.append(_seconds(op.vjp, X, R))  # at the forward's X: its checkpoints are reused
        X = x + 1e-3 * rng.standard_normal(x.shape)  # another point: the vjp pays its own checkpoint run
        vjp.append(_seconds(op.vjp, X, R))
    print(f"{a.problem} {' '.join(a.set)} ({p.N} unknowns, batch {a.batch}): forward "
          f"{[round(t, 3) for t in forward]} s, vjp from scratch {[round(t, 3) for t in vjp]} s, "
          f"after the forward {[round(t, 3) for t in after]} s")
    for name, t in (("from scratch", vjp), ("after the forward", after)):
        print(f"  vjp {name} / forward: {min(t) / min(forward):.2f} (minima), "
              f"{np.median(t) / np.median(forward):.2f} (medians)")


def _seconds(f, *args):
    t0 = time.perf_counter()
    f(*args)
    return time.perf_counter() - t0

if __name__ == "__main__":
    main()
