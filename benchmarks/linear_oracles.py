"""The best linear estimators of a scene, on the trainer's own test set: what a trained network must beat.

    python benchmarks/linear_oracles.py heat_boxes [--set n=32] [--set noise=0.01] [--draws 16384]

Prints the held-out relative L²(Ω) x-error (and per-node MAE, the SIP paper's unit) of

* best-α Tikhonov: ``x̂ = V diag(s/(s² + α)) Uᵀ y`` with ``P = U diag(s) Vᵀ`` (dense, Euclidean),
  the best of ``α = 10^k s_max²``, ``k = −30 … −1``, chosen with the test set's x (an oracle);
* the linear MMSE: ``x̂ = μ_x + C_xy (C_yy + r λ_max I)⁻¹ (y − μ_y)`` from ``--draws`` prior draws
  (independent of the test set), the best ridge ``r = 10^k``, ``k = −20 … −2`` (an oracle too).

Dense ``P``: for scenes up to a few thousand unknowns.
"""

import argparse

import numpy as np

import pdeinv
from pdeinv.cli.commands import parse_sets
from pdeinv.training.trainset import TEST_DATA, seed_stream


def best_tikhonov(problem, xt, yt) -> np.ndarray:
    """Best-α Tikhonov estimates of ``yt`` (α chosen with ``xt``: an oracle), dense ``P``, Euclidean."""
    U, s, Vt = np.linalg.svd(problem.operator.forward(np.eye(problem.N)).T, full_matrices=False)
    return min((((yt @ U) * (s / (s**2 + 10.0**k * s[0] ** 2))) @ Vt for k in range(-30, 0)),
               key=lambda e: float(np.mean(problem.relative_error(e, xt))))


def best_mmse(problem, xt, yt, xs, ys) -> np.ndarray:
    """Linear MMSE estimates of ``yt`` from the pairs ``(xs, ys)``, the best ridge chosen with ``xt``."""
    mx, my = xs.mean(0), ys.mean(0)
    Cyy, Cxy = (ys - my).T @ (ys - my) / len(ys), (xs - mx).T @ (ys - my) / len(ys)
    lam = np.linalg.eigvalsh(Cyy).max()
    return min((mx + (yt - my) @ np.linalg.solve(Cyy + 10.0**k * lam * np.eye(len(Cyy)), Cxy.T)
                for k in range(-20, -1)), key=lambda e: float(np.mean(problem.relative_error(e, xt))))


def oracles(problem, xt, yt, draws: int = 16384) -> dict:
    """``{name: (x_err, MAE)}`` of :func:`best_tikhonov` and :func:`best_mmse` (``draws`` prior draws)."""
    def scores(xhat):
        return float(np.mean(problem.relative_error(xhat, xt))), float(np.abs(xhat - xt).mean())

    xs, ys = problem.sample(draws, seed=12_345)
    return {"tikhonov": scores(best_tikhonov(problem, xt, yt)),
            "mmse": scores(best_mmse(problem, xt, yt, xs, ys))}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("problem")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--draws", type=int, default=16384)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-test", type=int, default=128)
    a = ap.parse_args()
    p = pdeinv.load_problem(a.problem, **parse_sets(a.set))
    xt, yt = p.sample(a.n_test, seed_stream(a.seed, TEST_DATA))
    for name, (err, mae) in oracles(p, xt, yt, a.draws).items():
        print(f"{a.problem} {' '.join(a.set)} {name}: x_err {err:.4f}, MAE {mae:.4f}")


if __name__ == "__main__":
    main()
