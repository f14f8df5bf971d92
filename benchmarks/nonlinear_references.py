"""The classical references of a nonlinear scene on the trainer's own test set: what a trained network
must beat where no matrix exists.

    python benchmarks/nonlinear_references.py sine_gordon_1d [--set noise=0.01] [--alphas 1e-1,1e-2]
        [--n-test 16] [--runs RUN_DIR ...]

Prints the held-out relative L²(Ω) x-error of per-sample regularized Gauss–Newton, 10 iterations from 0
(:func:`pdeinv.training.references.levenberg_marquardt`), on the test rows ``pdeinv train`` evaluates on:

* x-free: rel. α ``LM_ALPHAS[1]`` (1e-2), with noise stopped by Morozov's principle at 1.1 × the noise
  (what ``pdeinv classical`` gives without x), and its seconds per sample;
* the oracle: the best common α of ``--alphas`` (default ``LM_ALPHAS``), chosen with the test x;
* with ``--runs``, each ``pdeinv train`` run folder's network on the same rows (with ``--n-test`` below
  128 they are not the run's own first test rows: the draw depends on the count).
"""

import argparse

import numpy as np
import torch

import pdeinv
from pdeinv.cli.commands import parse_sets
from pdeinv.training.references import LM_ALPHAS, levenberg_marquardt
from pdeinv.training.trainset import TEST_DATA, seed_stream


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("problem")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--alphas", default=",".join(map(str, LM_ALPHAS)))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-test", type=int, default=128)
    ap.add_argument("--runs", nargs="*", default=[], help="run folders to score on the same rows")
    ap.add_argument("--skip-references", action="store_true", help="score --runs only")
    a = ap.parse_args()
    p = pdeinv.load_problem(a.problem, **parse_sets(a.set))
    xt, yt = p.sample(a.n_test, seed_stream(a.seed, TEST_DATA))
    noise = float(p.noise or 0.0)

    def err(X):
        return float(np.mean(p.relative_error(X, xt)))

    for run in a.runs:
        _, model = pdeinv.load_run(run)
        with torch.no_grad():
            out = model(torch.as_tensor(yt, dtype=next(model.parameters()).dtype)).double().numpy()
        print(f"{a.problem} {' '.join(a.set)} network {run}: x_err {err(out):.4f}")
    if a.skip_references:
        return
    X, info = levenberg_marquardt(p, yt, LM_ALPHAS[1], noise=noise)
    print(f"{a.problem} {' '.join(a.set)} x-free (rel. alpha {LM_ALPHAS[1]:g}): x_err {err(X):.4f}, "
          f"{info['s_per_sample']:.3g} s per sample")
    tried = {float(s): err(levenberg_marquardt(p, yt, float(s))[0]) for s in a.alphas.split(",")}
    best = min(tried, key=tried.get)
    print(f"{a.problem} {' '.join(a.set)} oracle: x_err {tried[best]:.4f} at rel. alpha {best:g} "
          f"(tried {', '.join(f'{k:g}: {v:.4f}' for k, v in tried.items())})")


if __name__ == "__main__":
    main()
