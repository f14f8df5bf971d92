"""Meshes: built-in intervals and unit squares (scikit-fem) and files read with meshio.

Boundary selection for Dirichlet conditions lives in :mod:`pdeinv.forms`; here
only the geometry is made or read.
"""

from __future__ import annotations

import os

import numpy as np
import skfem

from ._checks import count

#: meshio cell types we can turn into scikit-fem meshes, by topological dimension
_CELLS = {"line": skfem.MeshLine, "triangle": skfem.MeshTri}


def interval(n: int = 64, a: float = 0.0, b: float = 1.0) -> skfem.MeshLine:
    """Uniform mesh of ``[a, b]`` with ``n`` elements."""
    n = count(n, "n")
    if not b > a:
        raise ValueError(f"interval [{a}, {b}] is empty; expected a < b")
    return skfem.MeshLine(np.linspace(a, b, n + 1))


def unit_square(n: int = 32) -> skfem.MeshTri:
    """Unit square split into ``n x n`` squares, each cut into two triangles."""
    n = count(n, "n")
    x = np.linspace(0.0, 1.0, n + 1)
    return skfem.MeshTri.init_tensor(x, x)


def load(path: str | os.PathLike) -> skfem.Mesh:
    """Read a 1-D (line) or 2-D (triangle) mesh file with meshio.

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` for a file
    meshio cannot read or one whose cells are not all of one supported type.
    """
    import meshio

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"mesh file {path!r} does not exist")
    try:
        m = meshio.read(path)
    except (Exception, SystemExit) as err:  # meshio raises many types (even SystemExit)
        raise ValueError(
            f"mesh file {path!r} could not be read by meshio ({type(err).__name__}: {err}); "
            "expected a readable mesh format such as .msh, .vtu, .xdmf"
        ) from None
    kinds = {c.type for c in m.cells} - {"vertex"}
    top = [c for c in m.cells if c.type == "triangle"] or [c for c in m.cells if c.type == "line"]
    if not top or not kinds <= set(_CELLS):
        raise ValueError(
            f"mesh file {path!r} has cell types {sorted(kinds)}; "
            f"supported: a mesh made only of {' or '.join(_CELLS)} cells "
            "(boundary line cells beside triangles are ignored)"
        )
    kind = top[0].type
    cells = np.concatenate([c.data for c in m.cells if c.type == kind])
    dim = 2 if kind == "triangle" else 1
    pts = np.asarray(m.points[:, :dim], dtype=float)
    if kind == "triangle" and m.points.shape[1] > 2 and np.ptp(m.points[:, 2]) > 0:
        raise ValueError(f"mesh file {path!r} is not planar (z varies); expected a 2-D mesh")
    mesh = _CELLS[kind](np.ascontiguousarray(pts.T), np.ascontiguousarray(cells.T))
    used = np.unique(cells)
    if len(used) != len(pts):
        mesh = mesh.remove_unused_nodes()
    return mesh


def save(path: str | os.PathLike, mesh: skfem.Mesh, point_data: dict | None = None) -> None:
    """Write ``mesh`` (and nodal fields) with meshio; the format follows the suffix."""
    import meshio

    kind = "triangle" if mesh.dim() == 2 else "line"
    meshio.write(
        os.fspath(path),
        meshio.Mesh(mesh.p.T, [(kind, mesh.t.T)], point_data=point_data or {}),
    )
