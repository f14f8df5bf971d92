"""Finite-element assembly: P1/P2 Lagrange mass and stiffness on line, triangle and tetra meshes
(:data:`pdeinv.fem.mesh.CELL_TYPES`), Dirichlet condensation.

For a basis ``{phi_i}`` the mass and stiffness matrices are

    M_ij = ∫ phi_i phi_j dx,        K_ij = ∫ ∇phi_i · ∇phi_j dx.

Homogeneous Dirichlet conditions are imposed by *condensation*: only the rows
and columns of interior unknowns are kept, so every operator downstream acts on
``N`` free unknowns and stays symmetric positive definite. Natural (Neumann)
boundaries keep all unknowns. The lumped mass is the row-sum diagonal.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import skfem
from skfem.models.poisson import laplace, mass

from .._checks import choice
from .mesh import cell_type

#: Lagrange elements by meshio cell name (:data:`pdeinv.fem.mesh.CELL_TYPES`) and degree
ELEMENTS = {
    ("line", "P1"): skfem.ElementLineP1,
    ("line", "P2"): skfem.ElementLineP2,
    ("triangle", "P1"): skfem.ElementTriP1,
    ("triangle", "P2"): skfem.ElementTriP2,
    ("tetra", "P1"): skfem.ElementTetP1,
    ("tetra", "P2"): skfem.ElementTetP2,
}


def boundary_names(mesh: skfem.Mesh, names: str | Sequence[str]) -> list[str]:
    """``names`` as a list, each checked against the mesh's named boundaries."""
    names = [names] if isinstance(names, str) else list(names)
    known = sorted(mesh.boundaries or {})
    for name in names:
        if name not in known:
            has = f"it has {known}" if known else "it has no named boundaries (no tags in its file)"
            raise ValueError(f"boundary {name!r} is not a named boundary of the mesh; {has}")
    return names


@dataclass(frozen=True)
class Discretization:
    """Condensed FE matrices on the free unknowns and the maps back to the full mesh.

    ``M`` and ``K`` are CSR matrices over the ``N = len(free)`` free unknowns;
    ``points`` holds their coordinates, shape ``(dim, N)``; ``measure`` is ``|Ω|`` (the sum
    of the consistent mass over every unknown, before condensation and lumping).
    """

    basis: skfem.CellBasis
    M: sp.csr_matrix
    K: sp.csr_matrix
    free: np.ndarray
    measure: float = 1.0

    @property
    def N(self) -> int:
        return len(self.free)

    @property
    def dim(self) -> int:
        return self.basis.mesh.dim()

    @property
    def points(self) -> np.ndarray:
        return self.basis.doflocs[:, self.free]

    def extend(self, X: np.ndarray) -> np.ndarray:
        """Free-unknown fields ``(B, N)`` -> full FE coefficient vectors ``(B, basis.N)``."""
        X = np.atleast_2d(X)
        full = np.zeros((X.shape[0], self.basis.N))
        full[:, self.free] = X
        return full

    def vertex_values(self, X: np.ndarray) -> np.ndarray:
        """Free-unknown fields ``(B, N)`` -> values at the mesh vertices ``(B, nvertices)``: extended
        by zero to the Dirichlet unknowns; for P2 the vertex DOFs are the first ones in
        scikit-fem's numbering, so edge midpoints are dropped."""
        return self.extend(X)[:, self.basis.nodal_dofs[0]]

    def norm(self, X: np.ndarray) -> np.ndarray:
        """L²(Ω) norm of each row, ``sqrt(xᵀ M x)``, computed on the row divided by the power of two
        nearest its ``max |x|`` (exact): a norm float64 holds is returned even where ``xᵀ M x`` is not."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        top = np.max(np.abs(X), axis=1) if X.shape[1] else np.zeros(len(X))
        ok = (top > 0) & np.isfinite(top)
        exp = np.where(ok, np.frexp(np.where(ok, top, 1.0))[1], 0)
        Xs = np.ldexp(X, -exp[:, None])
        return np.ldexp(np.sqrt(np.einsum("bi,bi->b", Xs, (self.M @ Xs.T).T).clip(min=0)), exp)

    def relative_error(self, Xhat: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Relative L²(Ω) error per sample, ``‖x̂ − x‖_M / ‖x‖_M``; a row with ``x = 0`` is measured
        against the batch's scale instead (:func:`relative_norms`). Each norm is taken on a scaled row
        (:meth:`norm`), so fields whose squares leave float64 (1e±200) are measured too."""
        Xhat, X = np.asarray(Xhat, dtype=float), np.asarray(X, dtype=float)
        return relative_norms(self.norm(Xhat - X), self.norm(X))


def relative_norms(diff, ref) -> np.ndarray:
    """``diff_b / ref_b`` per row: the relative error of each row of a batch from its norms.

    A row whose reference is zero (an empty box: valid data) has no relative error of its own; it is
    divided by the root-mean-square of the batch's nonzero reference norms instead, so its error is on
    the data's scale, finite, and 0 when the row is reproduced exactly. A batch with no nonzero
    reference gives the absolute norms ``diff``. NaN stays NaN (never replaced by the scale).
    """
    diff, ref = np.asarray(diff, dtype=float), np.asarray(ref, dtype=float)
    zero = ref == 0
    if not zero.any():
        return diff / ref
    nonzero = ref[~zero & np.isfinite(ref)]
    scale = float(np.sqrt(np.mean(nonzero**2))) if nonzero.size else 1.0
    return diff / np.where(zero, scale, ref)


def discretize(
    mesh: skfem.Mesh,
    element: str = "P1",
    dirichlet: bool | str | Sequence[str] | np.ndarray = True,
    lumped: bool = False,
) -> Discretization:
    """Assemble mass and stiffness on ``mesh`` and condense Dirichlet unknowns.

    ``dirichlet`` is ``True`` (whole boundary), ``False`` (pure Neumann), the
    name(s) of boundaries in ``mesh.boundaries`` (tags read from a mesh file, or
    set with ``mesh.with_boundaries``), or an array of boundary DOF indices (e.g.
    from ``basis.get_dofs(facets)``).
    ``lumped=True`` replaces ``M`` with its row-sum diagonal (exact for P1 only
    in the sense of mass conservation; P2 lumping has zero/negative weights and
    is refused).
    """
    element = choice(element, "element", ("P1", "P2"))
    if lumped and element != "P1":
        raise ValueError(f"lumped=True with element={element!r}: mass lumping is only offered for 'P1'")
    basis = skfem.Basis(mesh, ELEMENTS[(cell_type(mesh).cell, element)]())
    M = mass.assemble(basis)
    K = laplace.assemble(basis)
    measure = float(M.sum())
    if lumped:
        M = sp.diags(np.asarray(M.sum(axis=1)).ravel()).tocsr()
    if dirichlet is True:
        fixed = basis.get_dofs().all()
    elif dirichlet is False:
        fixed = np.zeros(0, dtype=int)
    elif isinstance(dirichlet, str) or (len(dirichlet) and all(isinstance(d, str) for d in dirichlet)):
        fixed = basis.get_dofs(boundary_names(mesh, dirichlet)).all()
    else:
        fixed = np.asarray(dirichlet, dtype=int)
    free = basis.complement_dofs(fixed)
    if len(free) == 0:
        raise ValueError("the Dirichlet boundary removes every unknown; refine the mesh (n >= 2)")
    sub = np.ix_(free, free)
    return Discretization(
        basis=basis,
        M=sp.csr_matrix(M[sub]),
        K=sp.csr_matrix(K[sub]),
        free=free,
        measure=measure,
    )
