"""Linear solvers as strategy objects: ``solver(A)`` returns ``solve(B) = A⁻¹B`` and ``solve_T(B) = A⁻ᵀB``.

``B`` holds right-hand sides as *columns*, shape ``(N,)`` or ``(N, k)``; all
columns are solved at once with one factorization. Adjoints call ``solve_T``.
Each solver records whether ``A`` is ``symmetric`` (checked, :func:`is_symmetric`):
then ``solve_T`` is ``solve`` (SuperLU's ``trans='T'`` is ~40% slower for no gain);
otherwise SuperLU solves with the transposed factors, and the solvers that need a
symmetric matrix (Cholesky, CG) refuse it.

``default_solver`` takes a sparse Cholesky (cholespy) for a symmetric matrix when
installed and SuperLU otherwise; ``amg_cg`` is for meshes too large to factor.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .errors import ConvergenceError, NumericalError


def _require_finite(A: sp.spmatrix) -> None:
    """Refuse a matrix with NaN/Inf entries (a setting such as kappa or c overflowed it)."""
    data = sp.csr_matrix(A).data
    if not np.isfinite(data).all():
        raise ValueError(f"the system matrix has {int((~np.isfinite(data)).sum())} NaN/Inf entries: a "
                         "setting (kappa, c, T or steps) makes it overflow float64; use smaller values")


def is_symmetric(A: sp.spmatrix, rtol: float = 1e-13) -> bool:
    """``max|A − Aᵀ| ≤ rtol · max|A|`` (rounding in assembly leaves ~1e-16 relative)."""
    A = sp.csr_matrix(A)
    diff = abs(A - A.T)
    return diff.nnz == 0 or diff.max() <= rtol * abs(A).max()


def _require_symmetric(A, name: str) -> None:
    if not is_symmetric(A):
        raise ValueError(f"the {name} solver needs a symmetric matrix and this one is not; "
                         "use solver=pdeinv.SuperLU (LU, any square matrix)")


class SuperLU:
    """Direct sparse LU (SuperLU), factorized once, solved many times.

    A symmetric matrix uses the symmetric-mode ordering ``MMD_AT_PLUS_A``, which on
    the 2-D heat matrices gives ~30% less fill and ~25% faster solves than the
    default COLAMD; any other square matrix the default (COLAMD, partial pivoting).
    """

    name = "splu"

    def __init__(self, A: sp.spmatrix):
        _require_finite(A)
        self.symmetric = is_symmetric(A)
        opts = ({"permc_spec": "MMD_AT_PLUS_A", "options": {"SymmetricMode": True}}
                if self.symmetric else {})
        try:
            self.lu = sla.splu(sp.csc_matrix(A), **opts)
        except RuntimeError as err:  # "Factor is exactly singular"
            raise NumericalError(f"sparse LU failed ({err}): the system matrix is singular in float64; "
                                 "check the mesh and the settings (kappa, c, T, steps)") from None
        self.shape = A.shape

    def solve(self, B: np.ndarray) -> np.ndarray:
        return self.lu.solve(B)

    def solve_T(self, B: np.ndarray) -> np.ndarray:
        return self.lu.solve(B) if self.symmetric else self.lu.solve(B, trans="T")

    @property
    def fill(self) -> int:
        """Non-zeros in the factors (the cost of one solve per right-hand side)."""
        return self.lu.L.nnz + self.lu.U.nnz


class Cholesky:
    """Sparse Cholesky ``A = L Lᵀ`` (cholespy, CHOLMOD-style supernodal), for SPD ``A``.

    Measured on 2 cores for the 2-D heat matrix, 64 right-hand sides: about 3x
    faster than SuperLU at 961 unknowns and more at 3969 (see ``pdeinv bench``),
    agreeing to ~1e-15. Optional dependency: ``pip install cholespy``.
    """

    name = "cholesky"
    symmetric = True

    def __init__(self, A: sp.spmatrix):
        import cholespy
        import torch

        _require_symmetric(A, "Cholesky")
        C = sp.coo_matrix(A)
        self.n = A.shape[0]
        self.shape = A.shape
        self._torch = torch
        self.chol = cholespy.CholeskySolverD(
            self.n,
            torch.from_numpy(C.row.astype(np.int32)),
            torch.from_numpy(C.col.astype(np.int32)),
            torch.from_numpy(C.data.astype(np.float64)),
            cholespy.MatrixType.COO,
        )

    def solve(self, B: np.ndarray) -> np.ndarray:
        b = self._torch.from_numpy(np.ascontiguousarray(B, dtype=np.float64).reshape(self.n, -1))
        x = self._torch.empty_like(b)
        self.chol.solve(b, x)
        return x.numpy().reshape(B.shape)

    solve_T = solve


def default_solver(A: sp.spmatrix):
    """Sparse Cholesky for a symmetric ``A`` if cholespy is installed, else SuperLU (always available).

    A matrix with NaN/Inf entries is refused (``ValueError``) before either factorizes it."""
    _require_finite(A)
    if not is_symmetric(A):
        return SuperLU(A)
    try:
        return Cholesky(A)
    except ImportError:
        return SuperLU(A)


class AMGCG:
    """Conjugate gradients preconditioned by smoothed-aggregation AMG (pyamg).

    For meshes too large for a direct factorization. The AMG hierarchy is built
    once; each column is solved to relative residual ``rtol``. Results then agree
    with a direct solve only to about ``rtol``: adjoint identities hold to that
    accuracy, not to rounding.
    """

    name = "amg-cg"
    symmetric = True

    def __init__(self, A: sp.spmatrix, rtol: float = 1e-12, maxiter: int = 500):
        import pyamg

        _require_symmetric(A, "AMG-CG")
        self.A = sp.csr_matrix(A)
        self.ml = pyamg.smoothed_aggregation_solver(self.A)
        self.M = self.ml.aspreconditioner(cycle="V")
        self.rtol, self.maxiter = rtol, maxiter
        self.shape = A.shape

    def solve(self, B: np.ndarray) -> np.ndarray:
        cols = B.reshape(B.shape[0], -1)
        out = np.empty_like(cols, dtype=float)
        for j in range(cols.shape[1]):
            x, info = sla.cg(self.A, cols[:, j], rtol=self.rtol, maxiter=self.maxiter, M=self.M)
            if info != 0:
                raise ConvergenceError(
                    f"AMG-CG did not reach rtol={self.rtol} in {self.maxiter} iterations "
                    f"(column {j}); raise maxiter or use the direct solver SuperLU"
                )
            out[:, j] = x
        return out.reshape(B.shape)

    solve_T = solve


def amg_cg(rtol: float = 1e-12, maxiter: int = 500):
    """A solver factory with the given tolerance: ``solver=amg_cg(1e-10)``."""
    return lambda A: AMGCG(A, rtol=rtol, maxiter=maxiter)
