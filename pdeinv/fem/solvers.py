"""Linear solvers as strategy objects: ``solver(A)`` returns ``solve(B) = A⁻¹B`` and ``solve_T(B) = A⁻ᵀB``.

``B`` holds right-hand sides as *columns*, shape ``(N,)`` or ``(N, k)``; all
columns are solved at once with one factorization. Adjoints call ``solve_T``.
Each solver records whether ``A`` is ``symmetric`` (checked, :func:`is_symmetric`):
then ``solve_T`` is ``solve`` (SuperLU's ``trans='T'`` is ~40% slower for no gain);
otherwise SuperLU solves with the transposed factors, and the solvers that need a
symmetric matrix (Cholesky, CG) refuse it.

``default_solver(A, dim)`` takes AMG-CG for a symmetric matrix above the
:data:`AMG_CROSSOVER` of the mesh dimension, below it a sparse Cholesky (cholespy) when
installed, and SuperLU otherwise; ``solver_for(dim)`` binds the dimension (what
:class:`pdeinv.physics.Heat` uses); ``amg_cg(rtol)`` asks for AMG-CG explicitly.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ..errors import ConvergenceError, NumericalError


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
                         "use solver=pdeinv.fem.solvers.SuperLU (LU, any square matrix)")


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

    Agrees with SuperLU to ~1e-15 and is ~3x faster on the 2-D heat matrices (``pdeinv bench``).
    Optional dependency: ``pip install cholespy``.
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


#: Unknowns above which :func:`default_solver` takes AMG-CG instead of a direct factorization, by
#: mesh dimension (``None``: never). 3-D 50 000: where one factorization plus 100 solves costs as much as
#: AMG-CG (the factorization grows like N²); 2-D 1 000 000: where the factors approach 2 GB (the direct
#: solve is faster at every 2-D size); 1-D never (a tridiagonal factor is always cheapest). The table of
#: ``python benchmarks/crossover.py``: benchmarks/notes/scaling.md.
AMG_CROSSOVER = {1: None, 2: 1_000_000, 3: 50_000}


def _sparse_bytes(A) -> int:
    A = sp.csr_matrix(A)
    return int(A.data.nbytes + A.indices.nbytes + A.indptr.nbytes)


def default_solver(A: sp.spmatrix, dim: int | None = None):
    """The solver for ``A`` on a mesh of dimension ``dim``: AMG-CG for a symmetric ``A`` with
    more than ``AMG_CROSSOVER[dim]`` unknowns; below that a sparse Cholesky (cholespy) when
    installed, else SuperLU (always available; also for any non-symmetric ``A``).

    ``dim=None`` (dimension unknown) never picks AMG: the crossover differs ~10x between
    2-D and 3-D (factor fill grows like ``N log N`` in 2-D and ``N^{4/3}`` in 3-D), so no
    single size threshold is right. A matrix with NaN/Inf entries is refused (``ValueError``).
    """
    _require_finite(A)
    if not is_symmetric(A):
        return SuperLU(A)
    if dim is not None and dim not in AMG_CROSSOVER:
        raise ValueError(f"dim={dim!r} is not allowed; expected one of {sorted(AMG_CROSSOVER)} or None")
    if uses_amg(A.shape[0], dim):
        return AMGCG(A)
    try:
        return Cholesky(A)
    except ImportError:
        return SuperLU(A)


def uses_amg(n: int, dim: int | None) -> bool:
    """The rule of :func:`default_solver` for a symmetric matrix: ``n > AMG_CROSSOVER[dim]``."""
    limit = AMG_CROSSOVER.get(dim) if dim is not None else None
    return limit is not None and n > limit


def solver_for(dim: int | None):
    """``default_solver`` with the mesh dimension bound: a factory ``A -> solver``."""
    def factory(A):
        return default_solver(A, dim=dim)

    factory.dim = dim
    return factory


class AMGCG:
    """Conjugate gradients preconditioned by one smoothed-aggregation AMG V-cycle (pyamg).

    For meshes too large for a direct factorization (:data:`AMG_CROSSOVER`). The
    hierarchy ``A₀ = A, A_{l+1} = R_l A_l P_l`` (``R_l = P_lᵀ``, pyamg's smoothed
    aggregation) is built once in ``__init__`` and reused by every solve — all steps, all
    columns, forward and adjoint. Each column ``x`` of ``A X = B`` is iterated until
    ``‖b − A x‖₂ ≤ rtol ‖b‖₂``; results then agree with a direct solve only to about
    ``rtol · cond(A)``, and adjoint identities hold to that accuracy, not to rounding.

    ``block=True`` (default) runs one CG per column *in lockstep* on the ``(N, k)``
    block: every sparse product is a matrix–block product and the V-cycle (``ν``
    damped-Jacobi sweeps ``x ← x + ω D⁻¹(b − A x)`` before and after the coarse
    correction, ``ω = 4/(3 ρ(D⁻¹A))``; the same sweeps before and after, so the
    V-cycle is symmetric and a valid CG preconditioner) acts on all columns at once.
    ``block=False`` loops over the columns with ``scipy``'s CG and pyamg's own
    V-cycle (symmetric Gauss–Seidel): ~k times the Python and matrix traffic
    (``benchmarks/crossover.py`` compares them).

    Reports: ``rtol``, ``operator_complexity`` (Σ nnz(A_l) / nnz(A)), ``nbytes``
    (the hierarchy: every ``A_l``, ``P_l``, ``R_l``), ``levels``, ``iterations``
    (of the last block solve, max over columns; ``None`` after a column-loop solve).
    """

    name = "amg-cg"
    symmetric = True

    def __init__(self, A: sp.spmatrix, rtol: float = 1e-12, maxiter: int = 500, block: bool = True,
                 sweeps: int = 1):
        import pyamg
        from pyamg.util.linalg import approximate_spectral_radius

        if not (isinstance(rtol, (int, float)) and 0 < rtol < 1):
            raise ValueError(f"rtol={rtol!r} is not allowed; expected a relative residual 0 < rtol < 1")
        if isinstance(maxiter, bool) or not isinstance(maxiter, int) or maxiter < 1:
            raise ValueError(f"maxiter={maxiter!r} is not allowed; expected an integer >= 1")
        _require_finite(A)
        _require_symmetric(A, "AMG-CG")
        self.A = sp.csr_matrix(A, dtype=float)
        self.rtol, self.maxiter, self.block, self.sweeps = float(rtol), maxiter, bool(block), int(sweeps)
        self.shape = A.shape
        self.ml = pyamg.smoothed_aggregation_solver(self.A, symmetry="hermitian")
        self.M = self.ml.aspreconditioner(cycle="V")
        self._levels = []  # (A_l, P_l, R_l, ω/diag(A_l)) in CSR: pyamg's BSR products are ~2x slower here
        for lvl in self.ml.levels[:-1]:
            d = lvl.A.diagonal()
            rho = approximate_spectral_radius(sp.diags(1.0 / d) @ lvl.A)
            self._levels.append((sp.csr_matrix(lvl.A), sp.csr_matrix(lvl.P), sp.csr_matrix(lvl.R),
                                 ((4.0 / (3.0 * rho)) / d)[:, None]))
        self._coarse = sla.splu(sp.csc_matrix(self.ml.levels[-1].A))
        self.levels = len(self.ml.levels)
        self.operator_complexity = float(self.ml.operator_complexity())
        # pyamg's levels hold A, and P and R except the coarsest (instance attributes)
        self.nbytes = sum(_sparse_bytes(m) for lvl in self.ml.levels
                          for name, m in vars(lvl).items() if name in ("A", "P", "R"))
        self.iterations = 0

    def _vcycle(self, B: np.ndarray, level: int = 0) -> np.ndarray:
        """One symmetric V-cycle on a block of residuals ``B`` (``(n_l, k)``), from ``X = 0``."""
        if level == self.levels - 1:
            return self._coarse.solve(B)
        A, P, R, w = self._levels[level]
        X = w * B
        for _ in range(self.sweeps - 1):
            X += w * (B - A @ X)
        X += P @ self._vcycle(R @ (B - A @ X), level + 1)
        for _ in range(self.sweeps):
            X += w * (B - A @ X)
        return X

    def _block_cg(self, B: np.ndarray) -> np.ndarray:
        """Preconditioned CG on every column of ``B`` at once (columns that converged stop moving)."""
        X = np.zeros_like(B)
        R = B.copy()
        goal = self.rtol * np.linalg.norm(B, axis=0)
        active = np.linalg.norm(R, axis=0) > goal
        Z = self._vcycle(R)
        P = Z.copy()
        rz = np.einsum("ij,ij->j", R, Z)
        it = 0
        while active.any():
            if it == self.maxiter:
                raise self._not_converged(int(np.flatnonzero(active)[0]))
            it += 1
            AP = self.A @ P
            pap = np.einsum("ij,ij->j", P, AP)
            alpha = np.where(active, rz / np.where(active, pap, 1.0), 0.0)
            X += alpha * P
            R -= alpha * AP
            active &= np.linalg.norm(R, axis=0) > goal
            Z = self._vcycle(R)
            rz_new = np.einsum("ij,ij->j", R, Z)
            P = Z + np.where(active, rz_new / np.where(active, rz, 1.0), 0.0) * P
            rz = rz_new
        self.iterations = it
        return X

    def _not_converged(self, j: int) -> ConvergenceError:
        return ConvergenceError(f"AMG-CG did not reach rtol={self.rtol} in {self.maxiter} iterations "
                                f"(column {j}); raise maxiter or use the direct solver SuperLU")

    def _column_cg(self, cols: np.ndarray) -> np.ndarray:
        self.iterations = None  # scipy's cg does not report them
        out = np.empty_like(cols)
        for j in range(cols.shape[1]):
            x, info = sla.cg(self.A, cols[:, j], rtol=self.rtol, maxiter=self.maxiter, M=self.M)
            if info != 0:
                raise self._not_converged(j)
            out[:, j] = x
        return out

    def solve(self, B: np.ndarray) -> np.ndarray:
        cols = np.array(B, dtype=float).reshape(B.shape[0], -1)
        X = self._block_cg(cols) if self.block else self._column_cg(cols)
        return X.reshape(B.shape)

    solve_T = solve

    def __repr__(self):
        return (f"AMGCG(N={self.shape[0]}, rtol={self.rtol:g}, levels={self.levels}, "
                f"operator_complexity={self.operator_complexity:.2f}, {self.nbytes / 1e6:.3g} MB)")


def amg_cg(rtol: float = 1e-12, maxiter: int = 500, block: bool = True):
    """A solver factory with the given tolerance: ``solver=amg_cg(1e-10)``."""
    if not (isinstance(rtol, (int, float)) and 0 < rtol < 1):
        raise ValueError(f"rtol={rtol!r} is not allowed; expected a relative residual 0 < rtol < 1")
    return lambda A: AMGCG(A, rtol=rtol, maxiter=maxiter, block=block)
