"""The SIP paper's heat comparison (Holl, Koltun & Thuerey 2022, Fig. 4; tum-pbs/SIP heat/) on finite
elements: the same U-Net (``--net unet``, seed 0) trained on observations alone by SIP (the paper's
"Adam + PG": Adam on the proxy loss), Adam on the y-loss and HIG, with the linear references beside it.

    OMP_NUM_THREADS=1 python benchmarks/sip_heat.py [--n 32] [--steps 1000] [--methods sip adam hig]
        [--every 100] [--noise 0] [--rows R] [--problem heat_boxes] [--set KEY=VALUE] [--stop none]

heat_boxes (the paper's box prior, κT = 8 cells²) at ``--n`` cells per side (``--problem``: any scene
with nodal unknowns, e.g. heat_plate on its unstructured mesh or the nonlinear allen_cahn_1d), no prior
stage: ``x`` enters no loss, only the errors. The paper's protocol: every step trains on 32 new prior
draws (``fresh=True``, seeded per step, so every method sees the same draws; ``--rows R`` trains on R
fixed rows instead), the same 128 test draws and the same step count for every method; each row of the
table is one method after ``--steps`` steps, with its wall time (one thread, the methods one after the
other in one process). Columns: mean relative L²(Ω) error and per-node mean absolute error (the paper's
"x MAE") on the test draws, and their ratio to SIP's. The curve (``--every``) prints the test x-error
over steps and seconds.

Reference rows: SIP on the default linear network (``--net default --prior-fit 0``: the rule's linear
map, 30 full-batch steps) and the classical oracle on the test draws: best-α Tikhonov
(:func:`pdeinv.training.references.tikhonov_best`) on linear physics, per-sample regularized
Gauss–Newton at the best common α (:func:`~pdeinv.training.references.levenberg_marquardt`, what
``pdeinv classical`` runs) on nonlinear physics. The paper reports x-MAE 0.0123 (SIP) against 0.031
(Adam) at 64² after 6 000 GPU seconds.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")


def _mae(problem, model, test) -> float:
    import numpy as np
    import torch

    x, y = test
    dtype = next(model.parameters()).dtype
    with torch.no_grad():
        xhat = model(torch.as_tensor(y, dtype=dtype)).double().numpy()
    return float(np.mean(np.abs(xhat - x)))


def run(problem, method: str, steps: int, every: int, test, rows: int | None = None, stop="auto") -> dict:
    import torch

    import pdeinv
    from pdeinv.nets import unet

    torch.manual_seed(0)
    model = unet()(problem)
    curve = []
    start = time.perf_counter()

    def mark(record, _model):
        if "x_err" in record:
            curve.append((record["step"], time.perf_counter() - start, record["x_err"]))

    batch = 32
    data = {"fresh": True} if rows is None else {"n_train": rows}
    result = pdeinv.train(problem, method, model=model, prior=None, steps=steps, batch_size=batch,
                          eval_every=every, callbacks=[mark], progress=False, stop=stop, **data)
    return {"method": method, "x_err": result.metrics["x_err"], "mae": _mae(problem, result.model, test),
            "wall": time.perf_counter() - start, "curve": curve}


def linear_rows(problem, test) -> list[dict]:
    """SIP on the default linear network and the scene's classical oracle: best-α Tikhonov on linear
    physics, per-sample regularized Gauss–Newton at the best common α of ``LM_ALPHAS`` otherwise."""
    import numpy as np

    import pdeinv
    from pdeinv.physics.nonlinear import is_linear
    from pdeinv.training.references import LM_ALPHAS, levenberg_marquardt, tikhonov_best, tikhonov_path

    start = time.perf_counter()
    result = pdeinv.train(problem, "sip", prior=None, progress=False)
    rows = [{"method": "sip, linear map", "x_err": result.metrics["x_err"],
             "mae": _mae(problem, result.model, test), "wall": time.perf_counter() - start}]
    x, y = test
    if is_linear(problem.operator):
        best = tikhonov_best(problem, y, x)
        solve, _ = tikhonov_path(problem)
        mae = float(np.mean(np.abs(solve(y, best["alpha"]) - x)))
        rows.append({"method": "best-α Tikhonov", "x_err": best["x_err"], "mae": mae, "wall": 0.0})
        return rows
    tried = []
    for alpha in LM_ALPHAS:
        start = time.perf_counter()
        X, _ = levenberg_marquardt(problem, y, alpha)
        tried.append({"method": f"Gauss–Newton oracle (rel. α {alpha:g})",
                      "x_err": float(np.mean(problem.relative_error(X, x))),
                      "mae": float(np.mean(np.abs(X - x))), "wall": time.perf_counter() - start})
    rows.append(min(tried, key=lambda r: r["x_err"]))
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--problem", default="heat_boxes")
    parser.add_argument("--set", action="append", default=[], help="a scene setting KEY=VALUE")
    parser.add_argument("--n", type=int, default=32, help="heat_boxes' cells per side")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--every", type=int, default=100)
    parser.add_argument("--noise", type=float, default=0.0)
    parser.add_argument("--methods", nargs="+", default=["sip", "adam", "hig"])
    parser.add_argument("--stop", default="auto",
                        help="the stopping rule, as pdeinv train --stop takes it ('none': all --steps)")
    parser.add_argument("--rows", type=int, default=None,
                        help="train on this many fixed rows instead of new draws each step")
    args = parser.parse_args(argv)

    import torch

    import pdeinv
    from pdeinv.cli.commands import parse_sets
    from pdeinv.training.trainset import test_rows

    torch.set_num_threads(1)
    sets = {"n": args.n} if args.problem == "heat_boxes" else {}
    problem = pdeinv.load_problem(args.problem, **{**sets, "noise": args.noise, **parse_sets(args.set)})
    test = test_rows(problem, None, 128, 0)
    rows = [run(problem, m, args.steps, args.every, test, args.rows, args.stop) for m in args.methods]
    data = "new prior draws each step" if args.rows is None else f"{args.rows} fixed rows"
    print(f"{args.problem} {problem.N} unknowns noise={args.noise:g}: U-Net (--net unet), {args.steps} "
          f"steps of 32 ({data}), observations only")
    for r in rows:
        points = ", ".join(f"{s}: {e:.3f} ({t:.0f} s)" for s, t, e in r["curve"])
        print(f"  {r['method']:>5} curve: {points}")
    rows += linear_rows(problem, test)
    ref = next((r for r in rows if r["method"] == "sip"), rows[0])
    print("| method | x_err (rel. L²) | x MAE | wall s | x_err / SIP's | MAE / SIP's |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['method']} | {r['x_err']:.4f} | {r['mae']:.4f} | {r['wall']:.0f} | "
              f"{r['x_err'] / ref['x_err']:.2f} | {r['mae'] / ref['mae']:.2f} |")


if __name__ == "__main__":
    main()
