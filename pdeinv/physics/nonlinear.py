"""The physics interface: any differentiable forward map, linear or not (deepinv's ``Physics``).

A :class:`Physics` maps batches of fields ``X`` ``(B, n_in)`` to observations ``(B, n_out)``
and offers the two derivative products of the *discrete* map ``P`` at ``X``, row by row:

    jvp(X, V) = P'(X) V          (tangent map, forward mode)
    vjp(X, R) = P'(X)ᵀ R         (its exact transpose: ⟨P'(X)v, r⟩ = ⟨v, P'(X)ᵀ r⟩)

It declares ``linear`` (a class attribute, never probed from behaviour): ``True`` only for a map
with ``P(x) = P x``, for which :class:`~pdeinv.physics.base.LinearOperator` adds ``adjoint(R)``
without ``X`` and everything that only a fixed matrix has (compilation, modes, spectral filters,
Wiener targets, HIG's Kronecker routes). Code that needs one of those asks :func:`require_linear`
and gets an error naming what is missing, never a silently wrong number.

An optional local inverse (``local_inverse(y, x0) -> x``, with ``local_inverse(P x0, x0) = x0``)
is the physics' own offer to SIP (a reversible scheme: reverse stepping).
"""

from __future__ import annotations

import numpy as np

from .._checks import batch


class Physics:
    """Base class: input checks once, here; subclasses implement ``_forward``, ``_jvp``, ``_vjp``
    on float64 ``(B, ·)`` arrays."""

    #: declared capability: ``P(x) = P x`` for a fixed matrix ``P``
    linear: bool = False
    n_in: int
    n_out: int
    # what else it declares (:mod:`.capabilities`), with the defaults of a map whose observations
    # are records
    #: ``"field"``: observations are fields on the mesh, measured with its mass; ``"records"``: numbers
    output_space = "records"
    #: a spectral basis (:class:`.capabilities.Spectral`) or None
    modes = None
    #: the mass matrix of the unknowns, or None (Euclidean)
    mass = None
    #: a compiled backend (dense, SVD, modal) or None (time stepping, or no compiled form)
    backend = None
    #: ``final_state`` / ``reverse`` run the full state both ways (a time-reversible scheme)
    reversible = False
    #: ``P X`` in torch on a device (:class:`.backends.device.Placed`), or None (numpy on the CPU)
    torch_forward = None
    #: ``λ_max(PᵀP)`` in closed form (a zero-argument callable), or None (power iteration on use)
    max_gain_squared = None

    #: ``linearize(X0) -> (P(X0), tangent operator at X0)`` in closed form (the local inverse's
    #: Gauss–Newton step uses it), or None (jvp/vjp products)
    linearize = None
    #: the most rows one ``linearize`` call should be given (its fastest tangent fits in memory for that
    #: many: a local inverse solves more rows in chunks of it), or None (any number)
    linearize_rows: int | None = None

    #: ``jacobian(X) -> (B, n_out, n_in)``, the per-row Jacobians ``P'(x_b)`` in closed form (HIG's
    #: ``"chain"`` Jacobian), or None (HIG forms them from vjps)
    jacobian = None

    def jacobian_bytes(self, B: int) -> int:
        """The memory of :attr:`jacobian` on ``B`` rows, about (its result in float64)."""
        return 8 * B * self.n_out * self.n_in

    def forward_flops(self) -> float | None:
        """The flops of one row's :meth:`forward` by the operator's own cost model (sparse solves and
        products; BLAS products discounted by :data:`~pdeinv.physics.backends.compiled.BLAS_ADVANTAGE`),
        or None: not declared (a count priced by it, e.g. the prior stage's draws, is then not capped)."""
        return None

    def stepping(self):
        """The same map applied by time stepping (a :class:`.propagator.Propagator`), or None: this
        operator has no time-stepping form."""
        return None

    def forward(self, X) -> np.ndarray:
        """``P(X)`` row-wise: ``(B, n_in) -> (B, n_out)``."""
        A, single = batch(X, self.n_in, "X")
        Y = self._forward(A)
        return Y[0] if single else Y

    def jvp(self, X, V) -> np.ndarray:
        """``P'(X) V`` row-wise (the tangent of row ``b`` at row ``b`` of ``X``)."""
        A, single = batch(X, self.n_in, "X")
        Vb, _ = batch(V, self.n_in, "V")
        _same_rows(A, Vb, "V")
        Y = self._jvp(A, Vb)
        return Y[0] if single else Y

    def vjp(self, X, R) -> np.ndarray:
        """``P'(X)ᵀ R`` row-wise: the exact transpose of :meth:`jvp` at ``X``."""
        A, single = batch(X, self.n_in, "X")
        Rb, _ = batch(R, self.n_out, "R")
        _same_rows(A, Rb, "R")
        Z = self._vjp(A, Rb)
        return Z[0] if single else Z

    __call__ = forward

    def _forward(self, X):  # pragma: no cover - abstract
        raise NotImplementedError

    def _jvp(self, X, V):  # pragma: no cover - abstract
        raise NotImplementedError

    def _vjp(self, X, R):  # pragma: no cover - abstract
        raise NotImplementedError


def _same_rows(X, V, name):
    if V.shape[0] != X.shape[0]:
        raise ValueError(f"{name} has {V.shape[0]} rows and X has {X.shape[0]}; expected one row of "
                         f"{name} per row of X (the derivative is taken at each row of X)")


def is_linear(op) -> bool:
    """The declared capability ``op.linear``; an operator that declares nothing is refused by name
    (a guess either way would be a silent wrong answer somewhere)."""
    declared = op.linear if isinstance(op, Physics) else None
    if not isinstance(declared, bool):
        raise TypeError(f"{type(op).__name__} does not declare `linear` (True or False); subclass "
                        "pdeinv.physics.LinearOperator for a linear map or pdeinv.physics.Physics "
                        "(with jvp and vjp) for a nonlinear one")
    return declared


def require_linear(op, feature: str) -> None:
    """Raise a clear error if ``feature`` (which needs a fixed matrix ``P``) is asked of a nonlinear
    ``op``."""
    if not is_linear(op):
        raise NotImplementedError(
            f"{feature} needs a linear operator (a fixed matrix P); {op!r} declares linear=False. "
            "Use a method that only needs forward/jvp/vjp (--method gd, adam or sip)")
