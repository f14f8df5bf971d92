"""The linear-operator interface every physics model implements.

An operator maps batches of fields ``X`` of shape ``(B, N)`` to observations
``Y`` of shape ``(B, m)``. ``adjoint`` is the exact transpose of the *discrete*
forward map in the Euclidean inner product of coefficient vectors,

    ⟨P x, r⟩ = ⟨x, Pᵀ r⟩,

which is what back-propagation needs (not a discretized continuous adjoint).
Subclasses implement ``_forward`` and ``_adjoint`` on float64 ``(B, ·)`` arrays;
the public methods check shapes and finiteness once, here.
"""

from __future__ import annotations

import numpy as np

from .._checks import batch
from .nonlinear import Physics


class LinearOperator(Physics):
    """Base class: input checks, the transposed view ``.T``; a :class:`~.nonlinear.Physics` whose
    tangent is itself (``jvp(X, V) = P V``, ``vjp(X, R) = Pᵀ R``, ``X`` unused)."""

    linear = True
    #: number of unknowns and of observed values per sample
    n_in: int
    n_out: int

    def _jvp(self, X, V):
        return self._forward(V)

    def _vjp(self, X, R):
        return self._adjoint(R)

    def forward(self, X) -> np.ndarray:
        """``P X``, row-wise: ``(B, n_in) -> (B, n_out)``."""
        A, single = batch(X, self.n_in, "X")
        Y = self._forward(A)
        return Y[0] if single else Y

    def adjoint(self, R) -> np.ndarray:
        """``Pᵀ R``, row-wise: ``(B, n_out) -> (B, n_in)``."""
        A, single = batch(R, self.n_out, "R")
        X = self._adjoint(A)
        return X[0] if single else X

    __call__ = forward

    @property
    def T(self) -> LinearOperator:
        """The adjoint as an operator (its adjoint is ``self``)."""
        return Transposed(self)

    def _forward(self, X: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _adjoint(self, R: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError


class Transposed(LinearOperator):
    """``Pᵀ`` as an operator in its own right (used for double back-propagation)."""

    def __init__(self, op: LinearOperator):
        self.op = op
        self.n_in, self.n_out = op.n_out, op.n_in

    def _forward(self, X):
        return self.op._adjoint(X)

    def _adjoint(self, R):
        return self.op._forward(R)

    @property
    def T(self) -> LinearOperator:
        return self.op


class Matrix(LinearOperator):
    """A dense or sparse matrix as an operator (tests and small references)."""

    def __init__(self, A):
        import scipy.sparse as sp

        A = A if sp.issparse(A) else np.asarray(A)
        values = A.data if sp.issparse(A) else A
        if A.ndim != 2 or not np.issubdtype(values.dtype, np.number) or np.iscomplexobj(values):
            raise ValueError(f"Matrix(A): A is {A.ndim}-D of {values.dtype}; expected a 2-D matrix of real "
                             "numbers")
        if not np.isfinite(values).all():
            bad = int((~np.isfinite(values)).sum())
            raise ValueError(f"Matrix(A): A has {bad} NaN/Inf entries; expected finite numbers")
        self.A = A
        self.n_out, self.n_in = A.shape

    def _forward(self, X):
        return np.asarray((self.A @ X.T).T)

    def _adjoint(self, R):
        return np.asarray((self.A.T @ R.T).T)
