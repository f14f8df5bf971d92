"""Scaling against the mesh: build time, step time and peak memory per backend, 2-D and 3-D.

    OMP_NUM_THREADS=1 python benchmarks/scaling.py [--quick] [--sizes2 32 64 128 256]
        [--sizes3 8 16 24 32] [--budget 120] [--out benchmarks/notes/scaling.md]

For the unit square (``n × n × 2`` P1 triangles) and the unit cube (``n³ × 6`` P1
tetrahedra), Dirichlet boundary, it builds (``pdeinv.fem.forms.discretize`` and the
operators directly, not the scenes):

* heat ``Heat(M, K, κ=0.01, T=1, 100 steps, backward Euler)`` with ``backend`` =
  ``steps`` (the default direct solver, Cholesky or SuperLU), ``steps+amg``
  (:class:`pdeinv.fem.solvers.AMGCG`), ``modal``, ``dense``, ``svd``;
* wave ``Wave(M, K, c=1, T=0.5, 50 Newmark steps)`` (the mesh's direct solver, its default; SuperLU in the
  tables of benchmarks/notes/scaling.md measured before 2026-11-27) compiled to
  ``steps``, ``steps+amg``, ``dense``, ``svd``.

Columns: **build s** — constructing the operator and one forward of one column (so
lazily built parts, the factorization included, are counted); **step s** — forward and
adjoint of a batch of 32 fields (the physics of one training step), minimum of
``--repeats``; **peak MB** — growth of the peak resident set (``ru_maxrss``) of a forked
child process that does only that case, over the child's own peak at its start
(everything: numpy, SuperLU's and cholespy's factors, eigensolver work space; pages
shared with the parent and only read are not counted).
The disk cache is off (``PDEINV_NO_CACHE=1``), so builds are real. A case that takes
longer than ``--budget`` seconds (build + one step) stops that backend at larger sizes;
a backend that refuses (memory guard, too many modes) prints its reason.
``--quick``: 2-D n = 6, 8 and 3-D n = 3, 4, under 30 s.
"""

from __future__ import annotations

import argparse
import datetime
import multiprocessing as mp
import os
import resource
import sys
import time

import numpy as np

#: (physics, backend) pairs measured; 'steps+amg' is the stepping backend with AMG-CG
CASES = (("heat", "steps"), ("heat", "steps+amg"), ("heat", "modal"), ("heat", "dense"), ("heat", "svd"),
         ("wave", "steps"), ("wave", "steps+amg"), ("wave", "dense"), ("wave", "svd"))

COLUMNS = ("dim", "n", "N", "physics", "backend", "build s", "step s", "peak MB", "note")

SIZES = {2: (32, 64, 128, 256), 3: (8, 16, 24, 32)}
QUICK = {2: (6, 8), 3: (3, 4)}


def discretization(dim: int, n: int):
    """P1 on the unit square / cube with ``n`` subdivisions per side, Dirichlet boundary."""
    from pdeinv import mesh
    from pdeinv.fem.forms import discretize

    return discretize(mesh.unit_square(n) if dim == 2 else mesh.unit_cube(n))


def operator(disc, physics: str, backend: str):
    """The operator of one case (see the module docstring)."""
    from pdeinv.fem.solvers import AMGCG
    from pdeinv.physics import Heat, Wave

    amg = backend == "steps+amg"
    kind = "steps" if amg else backend
    if physics == "heat":
        kw = {"solver": AMGCG} if amg else {}
        return Heat(disc.M, disc.K, kappa=0.01, T=1.0, steps=100, backend=kind, measure=disc.measure,
                    dim=disc.dim, **kw)
    kw = {"solver": AMGCG} if amg else {}
    return Wave(disc.M, disc.K, c=1.0, T=0.5, steps=50, dim=disc.dim, **kw).compile(kind, disc.M)


def _peak_rss() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # kB on Linux


def _solver_note(op) -> str:
    """The stepping solver of ``op`` (its tolerance and hierarchy size for AMG-CG), or ''."""
    lu = getattr(op.stepping().scheme, "lu", None)
    return "" if lu is None else repr(lu) if hasattr(lu, "rtol") else type(lu).__name__


def _case(disc, physics, backend, repeats, queue):
    """In the child: build, time, report (seconds, seconds, bytes, note)."""
    base = _peak_rss()  # the child's own high-water mark at the fork (its page tables, not the parent's)
    try:
        t = time.perf_counter()
        op = operator(disc, physics, backend)
        op.forward(np.ones((1, op.n_in)))
        build = time.perf_counter() - t
        X = np.random.default_rng(0).standard_normal((32, op.n_in))
        step = np.inf
        for _ in range(max(1, repeats)):
            t = time.perf_counter()
            op.adjoint(op.forward(X))
            step = min(step, time.perf_counter() - t)
        note = _solver_note(op) if backend.startswith("steps") else op.kind
        queue.put((build, step, _peak_rss() - base, note))
    except Exception as err:  # noqa: BLE001 (a refusal is a result of the benchmark)
        queue.put((None, None, _peak_rss() - base, f"refused: {str(err).splitlines()[0][:90]}"))


def measure(disc, physics: str, backend: str, repeats: int = 2) -> dict:
    """One case in a forked child (clean peak memory); a dict with the table's columns."""
    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    child = ctx.Process(target=_case, args=(disc, physics, backend, repeats, queue))
    child.start()
    build, step, peak, note = queue.get()
    child.join()
    return {"dim": disc.dim, "N": disc.N, "physics": physics, "backend": backend, "build s": build,
            "step s": step, "peak MB": peak / 1e6, "note": note}


def table(sizes: dict, repeats: int = 2, budget: float = 120.0, cases=CASES, out=print) -> list[dict]:
    """Every case at every size (rows as dicts, each also printed as a markdown row)."""
    import pyamg  # noqa: F401  (imported once here, not in every forked child: a build is not an import)

    import pdeinv.fem.solvers  # noqa: F401
    import pdeinv.physics  # noqa: F401

    rows = []
    for dim, ns in sizes.items():
        slow = set()
        for n in ns:
            disc = discretization(dim, n)
            for physics, backend in cases:
                if (physics, backend) in slow:
                    continue
                row = {**measure(disc, physics, backend, repeats), "n": n}
                rows.append(row)
                out(markdown_row(row))
                if row["build s"] is None or row["build s"] + row["step s"] > budget:
                    slow.add((physics, backend))
    return rows


def _fmt(v) -> str:
    if v is None:
        return "–"
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def header() -> str:
    return "| " + " | ".join(COLUMNS) + " |\n|" + "---|" * len(COLUMNS)


def markdown_row(row: dict) -> str:
    return "| " + " | ".join(_fmt(row[c]) for c in COLUMNS) + " |"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python benchmarks/scaling.py", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny meshes, under 30 s (a smoke test)")
    ap.add_argument("--sizes2", type=int, nargs="*", default=list(SIZES[2]))
    ap.add_argument("--sizes3", type=int, nargs="*", default=list(SIZES[3]))
    ap.add_argument("--budget", type=float, default=120.0, help="seconds per case before a backend stops")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=None, help="also write the table to this markdown file")
    args = ap.parse_args(argv)
    os.environ["PDEINV_NO_CACHE"] = "1"
    sizes = dict(QUICK) if args.quick else {2: args.sizes2, 3: args.sizes3}
    command = " ".join(["python benchmarks/scaling.py", *(sys.argv[1:] if argv is None else argv)])
    lines = [f"Made by `{command}`"
             + f" on {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
             f"{os.cpu_count()} cores, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}.", "",
             header()]
    print("\n".join(lines), flush=True)

    def emit(line):
        lines.append(line)
        print(line, flush=True)

    table({d: ns for d, ns in sizes.items() if ns}, args.repeats, args.budget, out=emit)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
