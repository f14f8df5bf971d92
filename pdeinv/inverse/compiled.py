"""A local inverse that is linear in ``(y, x₀)`` jointly, compiled to one matrix.

Time reversal is such a map: ``P⁻¹_(x₀)(y) = R_u y + R_v v_T(x₀)`` (see
:mod:`.time_reversal`), both parts linear. Stored as ``G`` (``N × (m + N)``) with

    x̃ = G [y; x₀] = G_y y + G_x x₀,

it costs two BLAS products per batch instead of two stepping runs (a forward for
``v_T(x₀)``, then the reverse). ``G`` is built on the first call (GD and Adam never pay
for it) from the inverse itself on identity columns
(:func:`pdeinv.physics.backends.compiled.matrix`: ``m + N`` calls, each a forward and a reverse
run), under the dense budget, through the disk cache when the operator has a
:func:`~pdeinv.physics.backends.compiled.fingerprint`. It agrees with the stepping inverse to
rounding (``tests/test_compiled.py``). Only for inverses linear in both arguments: a
Tikhonov inverse with Morozov's α per sample is not.
"""

from __future__ import annotations

import numpy as np

from ._inputs import out, pair


class CompiledInverse:
    """``x̃ = y G_yᵀ + x₀ G_xᵀ`` for rows, from ``inverse(y, x0)`` linear in ``(y, x0)``."""

    def __init__(self, inverse, n_out: int, n_in: int, parts: dict | None = None):
        from ..physics.backends.compiled import budget_gb

        self.inverse, self.n_out, self.n_in = inverse, n_out, n_in
        need, have = 2 * 8 * n_in * (n_out + n_in) / 1e9, budget_gb()
        if need > have:
            raise ValueError(f"compiling {type(inverse).__name__} needs about {need:.2g} GB; the budget is "
                             f"{have:g} GB (PDEINV_DENSE_BUDGET_GB)")
        self._parts, self._G = parts, None

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """``(G_yᵀ, G_xᵀ)``, built on first use (a run that never calls the inverse never pays)."""
        if self._G is None:
            from ..physics.backends.compiled import matrix

            n_out, n_in, inverse = self.n_out, self.n_in, self.inverse

            def make():
                return {"G": matrix(lambda Z: inverse(Z[:, :n_out], Z[:, n_out:]), n_out + n_in, n_in)}

            if self._parts is None:
                G = make()["G"]
            else:
                from ..util.cache import cached

                G = cached("compiled_inverse", {**self._parts, "inverse": type(inverse).__name__,
                                                "shape": [n_in, n_out + n_in]}, make)["G"]
            self._G = (np.ascontiguousarray(G[:, :n_out].T), np.ascontiguousarray(G[:, n_out:].T))
        return self._G

    def __call__(self, y, x0) -> np.ndarray:
        Y, X0, single = pair(y, x0, self.n_out, self.n_in)
        GyT, GxT = self.matrices()
        return out(Y @ GyT + X0 @ GxT, single)

    def __repr__(self):
        return f"CompiledInverse({self.inverse!r})"
