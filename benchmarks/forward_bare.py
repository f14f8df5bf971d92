"""One forward map of a batch against a bare scikit-fem + SciPy backward-Euler loop (issue 35).

    OMP_NUM_THREADS=1 python benchmarks/forward_bare.py [--n 256] [--batch 32] [--repeats 2] [--backend auto]

Both sides compute heat_2d's map ``x ↦ u(T)`` (κ = 0.01, T = 1, 100 backward-Euler steps, P1 on
``n × n × 2`` triangles, ``u = 0`` on the boundary, ``(n−1)²`` interior unknowns; ``n = 256``:
65 025), on the same ``(batch, N)`` fields drawn from the scene's prior:

* **pdeinv**: ``pdeinv.load_problem('heat_2d', n=n)`` with the CLI defaults (``backend='auto'``: the
  truncated modal form ``P = Φ diag(r(dt μ)ⁿ) Φᵀ M``, or time stepping where that is cheaper), timed
  on ``problem.operator.forward(X)`` alone; the build (eigensolve, factorization) is reported apart
  (``--backend steps``: pdeinv's own time stepping, its factorization in the build);
* **bare**: ``M`` and ``K`` assembled with ``skfem.models.poisson.mass`` / ``laplace``, condensed to
  the interior nodes, ``A = M + dt κ K`` factorized once by ``scipy.sparse.linalg.splu`` (timed apart),
  then ``u ← A⁻¹ (M u)`` 100 times on the 32 columns at once.

The two sides alternate ``--repeats`` times in one process (one thread); printed: each time, the ratio
``pdeinv / bare`` (forward alone, and forward plus a one-time factorization where pdeinv steps), and the
relative difference ``‖Y_pdeinv − Y_bare‖ / ‖Y_bare‖`` (the modal form drops modes below
``tol = 1e-14`` of the largest gain, so ~1e-13 is exact); exit status 1 if it exceeds 1e-8.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
import skfem
from skfem.models.poisson import laplace, mass

import pdeinv


def bare_setup(n: int, kappa: float, dt: float):
    """``(M, splu(M + dt κ K))`` on the interior nodes of the ``n × n`` unit-square mesh, and the
    factorization's CPU seconds."""
    x = np.linspace(0.0, 1.0, n + 1)
    basis = skfem.Basis(skfem.MeshTri.init_tensor(x, x), skfem.ElementTriP1())
    free = basis.complement_dofs(basis.get_dofs().all())
    M = sp.csr_matrix(mass.assemble(basis)[np.ix_(free, free)])
    K = sp.csr_matrix(laplace.assemble(basis)[np.ix_(free, free)])
    t = time.process_time()
    lu = sla.splu(sp.csc_matrix(M + dt * kappa * K))
    return M, lu, time.process_time() - t


def bare_forward(M, lu, X: np.ndarray, steps: int) -> np.ndarray:
    """Backward Euler ``(M + dt κ K) uⁿ⁺¹ = M uⁿ``, all columns at once; batch-first in and out."""
    U = np.ascontiguousarray(X.T)
    for _ in range(steps):
        U = lu.solve(M @ U)
    return U.T


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--backend", default="auto", help="heat_2d's backend setting (default: the CLI's, auto)")
    args = ap.parse_args(argv)

    t = time.process_time()
    problem = pdeinv.load_problem("heat_2d", n=args.n, backend=args.backend)
    build = time.process_time() - t
    op, cfg = problem.operator, problem.settings
    steps, kappa = cfg["steps"], cfg["kappa"]
    dt = cfg["T"] / steps
    M, lu, factor = bare_setup(args.n, kappa, dt)
    X = problem.sample(args.batch, seed=0)[0]
    print(f"heat_2d n={args.n}: N={op.n_in}, batch {args.batch}, {steps} steps, κ={kappa}, dt={dt}")
    print(f"pdeinv backend: {op.kind} ({op.choice}); build {build:.2f} CPU s (not in the ratio)")
    print(f"bare: splu(M + dt κ K) {factor:.2f} CPU s, fill {lu.L.nnz + lu.U.nnz}")
    ratios, diffs = [], []
    for r in range(args.repeats):
        t = time.process_time()
        Y = op.forward(X)
        t_pde = time.process_time() - t
        t = time.process_time()
        Yb = bare_forward(M, lu, X, steps)
        t_bare = time.process_time() - t
        diff = np.linalg.norm(Y - Yb) / np.linalg.norm(Yb)
        ratios.append(t_pde / t_bare)
        diffs.append(diff)
        print(f"repeat {r}: pdeinv forward {t_pde:.4f} s, bare loop {t_bare:.4f} s "
              f"(with its factorization {t_bare + factor:.4f} s), ratio {t_pde / t_bare:.4f}, "
              f"relative difference {diff:.1e}")
    print(f"median ratio pdeinv / bare: {np.median(ratios):.4f} (goal ≤ 1.5)")
    if max(diffs) > 1e-8:  # not the same map: the ratio means nothing
        raise SystemExit(f"the two forward maps differ by {max(diffs):.1e} relative (> 1e-8)")


if __name__ == "__main__":
    main()
