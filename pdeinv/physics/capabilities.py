"""What an operator can do, asked by capability, never by concrete class.

Operators declare (all optional; a user's own :class:`~pdeinv.LinearOperator`
without them gets the safe answer):

* ``output_space``: ``"field"`` when an observation is a field on the mesh (then
  it is measured with the mass matrix ``M``: ``‖y‖²_M = yᵀMy``) or ``"records"``
  (plain numbers such as sensor time series, Euclidean). Undeclared: records.
* ``modes``: a modal basis with ``g``, ``Phi``, ``MPhi`` (``P = Φ diag(g) ΦᵀM``), or None.
* ``final_state(u₀, v₀)`` and ``reverse(u_T, v_T)``: the full state both ways
  (a reversible scheme: time reversal is an exact local inverse).
* ``symmetric``: every matrix of the scheme is symmetric.
"""

from __future__ import annotations


def observes_field(op) -> bool:
    """Whether ``op``'s observations are fields on the mesh (declared ``output_space == "field"``)."""
    return getattr(op, "output_space", "records") == "field"


def output_mass(op, M):
    """The observation-space mass: ``M`` for field observations, ``None`` (identity) for records."""
    return M if observes_field(op) else None


def modal_basis(op):
    """``op.modes`` (with ``g``, ``Phi``, ``MPhi``) if it has one, else ``None``."""
    return getattr(op, "modes", None)


def reversible(op) -> bool:
    """Whether ``op`` offers ``final_state`` and ``reverse`` (a time-reversible scheme)."""
    return all(callable(getattr(op, name, None)) for name in ("final_state", "reverse"))

