"""What an operator can do, asked by capability, never by concrete class.

Operators declare (on :class:`~pdeinv.physics.LinearOperator`, whose defaults a user's own operator
inherits: the safe answer):

* ``output_space``: ``"field"`` when an observation is a field on the mesh (then
  it is measured with the mass matrix ``M``: ``‖y‖²_M = yᵀMy``) or ``"records"``
  (plain numbers such as sensor time series, Euclidean). Undeclared: records.
* ``modes``: a spectral basis, i.e. a :class:`Spectral` (``P = out diag(g) Inᵀ``), or None.
* ``reversible``: ``final_state(u₀, c₀)`` and ``reverse(u_T, c_T)`` run the full state both ways
  (declared by a time-reversible scheme, Newmark or leapfrog: time reversal is a local inverse).
* ``symmetric``: every matrix of the scheme is symmetric (the scheme's answer, :mod:`.schemes`).
"""

from __future__ import annotations


class Spectral:
    """A spectral basis, the one declaration of "has modes": ``P = out diag(g) Inᵀ`` exactly (to the
    basis' tolerance), with ``proj`` and ``synth`` for the filters (``c = (y − y₀) proj`` are the
    coefficients of a residual, ``synth`` turns coefficients back into a field) and ``mass_out``
    (the observation-space mass, None for records). forward ``((X In) g) outᵀ``, adjoint
    ``((R out) g) Inᵀ``: exact transposes. Subclasses: the modal heat basis
    (:class:`.modal.Modal`), the compiled SVD and its lazy form (:mod:`.compiled`)."""

    @property
    def k(self) -> int:
        return len(self.g)

    def forward(self, X):
        return ((X @ self.In) * self.g) @ self.out.T

    def adjoint(self, R):
        return ((R @ self.out) * self.g) @ self.In.T

    def flops(self) -> float:
        """One column's :meth:`forward`: ``2k(N + m)``."""
        return 2.0 * self.k * (self.In.shape[0] + self.out.shape[0])


def observes_field(op) -> bool:
    """Whether ``op``'s observations are fields on the mesh (declared ``output_space == "field"``)."""
    return op.output_space == "field"


def output_mass(op, M):
    """The observation-space mass: ``M`` for field observations, ``None`` (identity) for records."""
    return M if observes_field(op) else None


def modal_basis(op) -> Spectral | None:
    """``op.modes`` if it is a :class:`Spectral` basis (``g``, ``In``, ``out``, ``proj``, ``synth``),
    else ``None``."""
    return op.modes if isinstance(op.modes, Spectral) else None


def reversible(op) -> bool:
    """Whether ``op`` declares ``reversible`` (a time-reversible scheme observed at the final field:
    ``final_state`` and ``reverse`` run the full state both ways, :class:`.propagator.Propagator`)."""
    return bool(op.reversible)
