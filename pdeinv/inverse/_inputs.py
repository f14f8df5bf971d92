"""Input checks shared by the local inverse simulators: ``(y, x0)`` as matching batches."""

from __future__ import annotations

import numpy as np

from .._checks import batch


def pair(y, x0, n_out: int, n_in: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """``y`` as float64 ``(B, n_out)``, ``x0`` as ``(B, n_in)``, and whether both were 1-D.

    Raises ``ValueError`` naming the argument for wrong shapes, NaN/Inf, or
    batch sizes that differ.
    """
    Y, single_y = batch(y, n_out, "y")
    X0, single_x = batch(x0, n_in, "x0")
    if Y.shape[0] != X0.shape[0]:
        raise ValueError(f"y has {Y.shape[0]} samples but x0 has {X0.shape[0]}; "
                         "expected one x0 row per y row")
    return Y, X0, single_y and single_x


def out(X: np.ndarray, single: bool) -> np.ndarray:
    return X[0] if single else X


def mass_norms(M, X: np.ndarray) -> np.ndarray:
    """``‖x‖_M`` per row of ``X`` (``M=None``: Euclidean)."""
    MX = X if M is None else np.asarray((M @ X.T).T)
    return np.sqrt(np.einsum("bi,bi->b", X, MX).clip(min=0))


def mass_trace(M, n: int) -> float:
    """``tr(M)``: ``E‖ε‖²_M / σ²`` for white noise ``ε ~ N(0, σ²I)`` (``M=None``: ``n``)."""
    return float(n) if M is None else float(M.diagonal().sum())


def given_forward(y0, X0: np.ndarray, n_out: int) -> np.ndarray:
    """``y0 = P x0`` from a caller (:class:`~.protocol.ReusesForward`) as float64 ``(B, n_out)``, one row
    per row of ``X0``."""
    Y0, _ = batch(y0, n_out, "y0")
    if Y0.shape[0] != X0.shape[0]:
        raise ValueError(f"y0 has {Y0.shape[0]} samples but x0 has {X0.shape[0]}; "
                         "expected y0 = P x0 row by row")
    return Y0
