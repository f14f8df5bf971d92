"""Where AMG-CG overtakes a direct factorization, measured per mesh dimension.

    OMP_NUM_THREADS=1 python benchmarks/crossover.py [--dims 2 3] [--steps 100] [--rhs 32] [--budget 60]

(smallest setting: ``--dims 2 --scenes heat --sizes2 16 --repeats 1``, a few seconds)

For each unit-square (``MeshTri.init_tensor``, ``n × n × 2`` P1 triangles) or unit-cube
(``MeshTet.init_tensor``, ``n³ × 6`` P1 tetrahedra) mesh it assembles, on the interior
unknowns, the system matrices a run factors once:

* heat, backward Euler: ``A = M + dt κ K`` (heat scenes' defaults: κ = 0.01, T = 1, 100 steps);
* wave, Newmark: ``A = M + (c dt / 2)² K`` (wave scenes' defaults: c = 1, T = 0.5, 50 steps),

and times, interleaved, what a run does with ``A``: **setup** (the factorization, or the
AMG hierarchy) and **one block solve** of ``--rhs`` right-hand sides (forward and adjoint
solves are the same solve: every ``A`` here is symmetric). The cost of a run is

    run = setup + steps · solve        (reported for ``--steps``; recompute for others)

Solvers: ``cholesky`` (cholespy, the default direct solver), ``splu`` (SuperLU, the fallback),
``amg`` (:class:`pdeinv.fem.solvers.AMGCG`, block CG, ``rtol`` 1e-12) and ``amg-loop`` (the same
hierarchy, scipy CG column by column with pyamg's V-cycle; only while it fits the budget).
Memory: the growth of the process's resident set across the setup (``/proc/self/statm``; the
factors of cholespy are not visible to tracemalloc), and for ``splu`` and ``amg`` the exact
bytes of the factors (``nnz(L) + nnz(U)``) and of the hierarchy. ``err``: the largest
relative difference of the AMG solution from the Cholesky one.

A size is skipped for a solver once its previous size took more than ``--budget`` seconds
of setup + one solve (direct solvers in 3-D fill fast). Times are the minimum of
``--repeats`` runs on a shared machine: compare ratios within one row.
"""

from __future__ import annotations

import argparse
import datetime
import time

import numpy as np

from pdeinv import mesh as meshes
from pdeinv.fem.forms import discretize

#: (heat dt κ, Newmark (c dt / 2)²) at the scenes' defaults
SCENES = {"heat": lambda M, K: M + (1.0 / 100) * 0.01 * K,
          "wave": lambda M, K: M + (1.0 * (0.5 / 50) / 2) ** 2 * K}

#: mesh subdivisions measured by default, per dimension
SIZES = {2: (64, 128, 256, 512, 768), 3: (8, 12, 16, 24, 32, 40)}


def mesh(dim: int, n: int):
    """The unit square (``dim=2``) or unit cube (``dim=3``) with ``n`` subdivisions per side."""
    return meshes.unit_square(n) if dim == 2 else meshes.unit_cube(n)


def matrix(dim: int, n: int, scene: str = "heat"):
    """The scene's system matrix ``A`` (CSR) on the interior unknowns of the ``dim``-D mesh."""
    disc = discretize(mesh(dim, n))
    return SCENES[scene](disc.M, disc.K).tocsr()


def rss() -> int:
    """Resident set size of this process now, in bytes (Linux; 0 elsewhere)."""
    try:
        with open("/proc/self/statm") as fh:
            import os

            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return 0


def solvers(include_loop: bool = True) -> dict:
    """``name -> factory A -> solver`` for the comparison."""
    from pdeinv.fem.solvers import AMGCG, Cholesky, SuperLU

    out = {"cholesky": Cholesky, "splu": SuperLU, "amg": AMGCG}
    if include_loop:
        out["amg-loop"] = lambda A: AMGCG(A, block=False)
    return out


def measure(A, name: str, factory, B: np.ndarray, repeats: int = 2) -> dict:
    """Setup and one block-solve time of ``factory`` on ``A``, its memory, and its solution."""
    before = rss()
    t = time.perf_counter()
    solver = factory(A)
    setup = time.perf_counter() - t
    grown = max(rss() - before, 0)
    solve, X = np.inf, None
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        X = solver.solve(B)
        solve = min(solve, time.perf_counter() - t)
    exact = getattr(solver, "fill", None)
    exact = 12 * exact if exact is not None else getattr(solver, "nbytes", None)
    row = {"solver": name, "setup_s": setup, "solve_s": solve, "rss_mb": grown / 1e6,
           "bytes_mb": None if exact is None else exact / 1e6,
           "iterations": getattr(solver, "iterations", None),
           "complexity": getattr(solver, "operator_complexity", None)}
    return row, X


def sweep(dims=(2, 3), scenes=("heat", "wave"), steps: int = 100, rhs: int = 32, budget: float = 60.0,
          repeats: int = 2, sizes: dict | None = None, loop_upto: int = 200_000, out=print) -> list[dict]:
    """Measure every (dim, scene, size, solver); rows as dicts (also printed through ``out``)."""
    rows = []
    for dim in dims:
        for scene in scenes:
            slow = set()
            for n in (sizes or SIZES)[dim]:
                A = matrix(dim, n, scene)
                N = A.shape[0]
                B = np.random.default_rng(0).standard_normal((N, rhs))
                ref = None
                for name, factory in solvers().items():
                    if name in slow or (name == "amg-loop" and N > loop_upto):
                        continue
                    row, X = measure(A, name, factory, B, repeats)
                    if name == "cholesky":
                        ref = X
                    err = None if ref is None or name == "cholesky" else float(
                        np.abs(X - ref).max() / np.abs(ref).max())
                    row.update(dim=dim, scene=scene, n=n, N=N, nnz=A.nnz, err=err,
                               run_s=row["setup_s"] + steps * row["solve_s"])
                    rows.append(row)
                    out(format_row(row))
                    if row["setup_s"] + row["solve_s"] > budget:
                        slow.add(name)
                    del X
    return rows


HEADER = ("| dim | scene | n | N | solver | setup s | solve s (×{rhs}) | run s ({steps} steps) | "
          "RSS MB | bytes MB | it | err |")


def _f(v, fmt):
    return "–" if v is None else format(v, fmt)


def format_row(r: dict) -> str:
    return (f"| {r['dim']} | {r['scene']} | {r['n']} | {r['N']} | {r['solver']} | {r['setup_s']:.3g} | "
            f"{r['solve_s']:.3g} | {r['run_s']:.3g} | {r['rss_mb']:.0f} | {_f(r['bytes_mb'], '.0f')} | "
            f"{_f(r['iterations'], 'd')} | {_f(r['err'], '.1e')} |")


def crossover(rows: list[dict], direct: str = "cholesky") -> dict:
    """Per (dim, scene): the smallest N at which ``amg``'s run time beats ``direct``'s (or ``None``)."""
    out = {}
    for key in sorted({(r["dim"], r["scene"]) for r in rows}):
        runs = {}
        for r in rows:
            if (r["dim"], r["scene"]) == key and r["solver"] in (direct, "amg"):
                runs.setdefault(r["N"], {})[r["solver"]] = r["run_s"]
        wins = [N for N, t in sorted(runs.items()) if "amg" in t and t["amg"] < t.get(direct, np.inf)]
        out[key] = wins[0] if wins else None
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python benchmarks/crossover.py", description=__doc__.split("\n")[0])
    ap.add_argument("--dims", type=int, nargs="+", default=[2, 3], choices=[2, 3])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--steps", type=int, default=100, help="solves per run (time steps)")
    ap.add_argument("--rhs", type=int, default=32, help="right-hand sides per solve (batch)")
    ap.add_argument("--budget", type=float, default=60.0,
                    help="skip a solver after a size slower than this (s)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--sizes2", type=int, nargs="+", default=list(SIZES[2]))
    ap.add_argument("--sizes3", type=int, nargs="+", default=list(SIZES[3]))
    args = ap.parse_args(argv)
    print(f"# crossover, {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC\n")
    print(HEADER.format(rhs=args.rhs, steps=args.steps))
    print("|" + "---|" * 12)
    rows = sweep(args.dims, args.scenes, args.steps, args.rhs, args.budget, args.repeats,
                 {2: args.sizes2, 3: args.sizes3}, out=lambda s: print(s, flush=True))
    print()
    for (dim, scene), N in crossover(rows).items():
        print(f"crossover {dim}-D {scene}: AMG-CG faster than Cholesky from N = {N}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
