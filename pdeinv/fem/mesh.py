"""Meshes: built-in intervals, unit squares and unit cubes (scikit-fem) and files read with meshio.

One table, :data:`CELL_TYPES`, says which meshes exist here: a scikit-fem mesh class, the
meshio name of its cells, the meshio name of its facets and its dimension —

    MeshLine1 ↔ "line" (facets "vertex", 1-D), MeshTri1 ↔ "triangle" ("line", 2-D),
    MeshTet1 ↔ "tetra" ("triangle", 3-D).

:func:`load`, :func:`save` and :mod:`pdeinv.io.export` go through it; any other mesh class or
cell type (quads, hexahedra, quadratic cells, mixed cells) is refused with a ``ValueError``
naming it, never written as something else.

Named boundaries travel with the mesh (``mesh.boundaries``: name -> facet indices, kept
by ``refined()``). Files carry them as tagged facet cells: gmsh physical groups
(``gmsh:physical`` cell data named through ``field_data``) or meshio ``cell_sets``;
:func:`save` writes them back as gmsh 2.2 physical groups. Dirichlet selection by name
or by geometry lives in :mod:`pdeinv.fem.forms`.
"""

from __future__ import annotations

import contextlib
import io
import os
from dataclasses import dataclass

import numpy as np
import skfem

from .._checks import count
from ..util import memory


@dataclass(frozen=True)
class CellType:
    """One supported kind of mesh: scikit-fem class ↔ meshio cell and facet names, dimension."""

    mesh: type
    cell: str
    facet: str
    facet_word: str  # what a facet is called in messages
    dim: int


#: the supported meshes, by increasing dimension (see the module docstring)
CELL_TYPES = (
    CellType(skfem.MeshLine1, "line", "vertex", "end points", 1),
    CellType(skfem.MeshTri1, "triangle", "line", "edges", 2),
    CellType(skfem.MeshTet1, "tetra", "triangle", "faces", 3),
)
_BY_CELL = {c.cell: c for c in CELL_TYPES}


def cell_type(mesh: skfem.Mesh) -> CellType:
    """The :data:`CELL_TYPES` row of ``mesh`` (its exact class); ``ValueError`` if there is none."""
    for row in CELL_TYPES:
        if type(mesh) is row.mesh:
            return row
    raise ValueError(f"mesh of type {type(mesh).__name__} is not supported; expected one of "
                     f"{', '.join(c.mesh.__name__ for c in CELL_TYPES)} "
                     f"(meshio cells {', '.join(_BY_CELL)})")


def interval(n: int = 64, a: float = 0.0, b: float = 1.0) -> skfem.MeshLine:
    """Uniform mesh of ``[a, b]`` with ``n`` elements."""
    n = count(n, "n")
    memory.check_mesh(n + 1, 1, f"an interval mesh of n={n} elements", "use a smaller n")
    if not b > a:
        raise ValueError(f"interval [{a}, {b}] is empty; expected a < b")
    return skfem.MeshLine(np.linspace(a, b, n + 1))


def unit_square(n: int = 32) -> skfem.MeshTri:
    """Unit square split into ``n x n`` squares, each cut into two triangles."""
    n = count(n, "n")
    memory.check_mesh((n + 1) ** 2, 2, f"a unit-square mesh with n={n}", "use a smaller n")
    x = np.linspace(0.0, 1.0, n + 1)
    return skfem.MeshTri.init_tensor(x, x)


def unit_cube(n: int = 8) -> skfem.MeshTet:
    """Unit cube split into ``n x n x n`` cubes, each cut into six tetrahedra (scikit-fem's
    ``MeshTet.init_tensor``): ``(n+1)³`` vertices, ``6n³`` cells, ``(n−1)³`` interior vertices."""
    n = count(n, "n")
    memory.check_mesh((n + 1) ** 3, 3, f"a unit-cube mesh with n={n}", "use a smaller n")
    x = np.linspace(0.0, 1.0, n + 1)
    return skfem.MeshTet.init_tensor(x, x, x)


def refined(mesh: skfem.Mesh, times: int, name: str = "refine") -> skfem.Mesh:
    """``mesh`` refined uniformly ``times`` times (each splits an edge in two: ×2^dim cells),
    refused first (:mod:`pdeinv.util.memory`) when the result would not fit."""
    times = count(times, name, minimum=0)
    if not times:
        return mesh
    dim = mesh.dim()
    nodes = mesh.p.shape[1] * float(2 ** dim) ** times
    memory.check_mesh(nodes, dim, f"{name}={times} of a mesh of {mesh.p.shape[1]} nodes",
                      f"use a smaller {name}")
    return mesh.refined(times)


def check_geometry(points: np.ndarray, cells: np.ndarray, where: str) -> None:
    """Refuse non-finite coordinates, coincident nodes and cells of zero size (``ValueError``).

    ``points`` ``(nv, dim)``, ``cells`` ``(ne, dim + 1)`` simplices. A cell counts as degenerate
    when its measure is below 1e-12 of the mean cell's: a zero-area triangle makes the stiffness
    matrix singular, and duplicated nodes split the mesh into unconnected pieces.
    """
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        raise ValueError(f"{where}: node {int(bad[0])} has coordinates {points[bad[0]].tolist()} "
                         f"({len(bad)} non-finite node(s)); expected finite coordinates")
    _, first, counts = np.unique(points, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        dup = points[first[np.argmax(counts > 1)]]
        same = np.flatnonzero((points == dup).all(axis=1))
        raise ValueError(f"{where}: nodes {', '.join(map(str, same.tolist()))} coincide at {dup.tolist()} "
                         f"({int((counts - 1).sum())} duplicated node(s)); expected distinct nodes "
                         "(merge them, e.g. gmsh's Coherence)")
    edges = points[cells[:, 1:]] - points[cells[:, :1]]  # (ne, dim, dim)
    size = np.abs(np.linalg.det(edges)) if edges.shape[1] == edges.shape[2] else np.zeros(len(cells))
    flat = np.flatnonzero(size <= 1e-12 * max(float(size.mean()), np.finfo(float).tiny))
    if len(flat):
        raise ValueError(f"{where}: cell {int(flat[0])} (nodes {cells[flat[0]].tolist()}) has zero size "
                         f"({len(flat)} degenerate cell(s)); expected cells of positive area/volume")


def load(path: str | os.PathLike, dim: int | None = None) -> skfem.Mesh:
    """Read a mesh file with meshio: line (1-D), triangle (2-D) or tetra (3-D) cells; with ``dim``
    (what a problem module expects: ``heat_2d`` passes 2) a mesh of another dimension is refused.

    Cells of lower dimension beside them (vertex, line, triangle) are boundary tags when
    they are facets in a physical group or cell set, and are ignored otherwise. Raises
    ``FileNotFoundError`` for a missing file and ``ValueError`` for a file meshio cannot
    read, one with a cell type outside :data:`CELL_TYPES`, one whose points leave the
    mesh's dimension (a 2-D mesh with varying z), or bad geometry (:func:`check_geometry`:
    NaN/Inf coordinates, coincident nodes, cells of zero size); a directory is a ``ValueError``.
    """
    import meshio

    path = os.fspath(path)
    if os.path.isdir(path):
        raise ValueError(f"mesh file {path!r} is a directory; expected a mesh file such as .msh, .vtu")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"mesh file {path!r} does not exist")
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # its gmsh reader prints blank lines to stdout
            m = meshio.read(path)
    except (Exception, SystemExit) as err:  # meshio raises many types (even SystemExit)
        raise ValueError(
            f"mesh file {path!r} could not be read by meshio ({type(err).__name__}: {err}); "
            "expected a readable mesh format such as .msh, .vtu, .xdmf"
        ) from None
    kinds = {c.type for c in m.cells} - {"vertex"}
    found = [c for c in CELL_TYPES if c.cell in kinds]
    if not found or not kinds <= set(_BY_CELL):
        raise ValueError(
            f"mesh file {path!r} has cell types {sorted(kinds)}; supported: a mesh of "
            f"{', '.join(list(_BY_CELL)[:-1])} or {list(_BY_CELL)[-1]} cells (lower-dimensional cells "
            "beside them are read as boundary tags or ignored)"
        )
    kind = found[-1]
    if dim is not None and kind.dim != dim:
        want = next((c for c in CELL_TYPES if c.dim == dim), None)
        raise ValueError(f"mesh file {path!r} holds a {kind.dim}-D mesh ({kind.cell} cells); this problem "
                         f"expects a {dim}-D mesh" + (f" ({want.cell} cells)" if want else ""))
    cells = np.concatenate([c.data for c in m.cells if c.type == kind.cell])
    pts = np.asarray(m.points, dtype=float)
    if cells.size and (cells.min() < 0 or cells.max() >= len(pts)):
        bad = int(cells.max()) if cells.max() >= len(pts) else int(cells.min())
        raise ValueError(f"mesh file {path!r}: a {kind.cell} cell refers to node {bad}, but the file has "
                         f"{len(pts)} nodes (0 … {len(pts) - 1}); the file is inconsistent")
    if pts.shape[1] > kind.dim and np.ptp(pts[:, kind.dim:], axis=0).max() > 0:
        raise ValueError(f"mesh file {path!r} has {kind.cell} cells but its points vary in more than "
                         f"{kind.dim} coordinates; expected a {kind.dim}-D mesh")
    used = np.unique(cells)
    index = np.full(len(pts), -1)
    index[used] = np.arange(len(used))  # drop nodes no cell uses (e.g. gmsh geometry points)
    check_geometry(pts[used, :kind.dim], index[cells], f"mesh file {path!r}")
    mesh = kind.mesh(np.ascontiguousarray(pts[used, :kind.dim].T), np.ascontiguousarray(index[cells].T))
    tags = {name: index[nodes] for name, nodes in _facet_tags(m, kind.facet).items()}
    return mesh.with_boundaries(_facets_of(mesh, tags, path)) if tags else mesh


def _facet_tags(m, facet: str) -> dict[str, np.ndarray]:
    """Named sets of ``facet`` cells (node tuples) in a meshio mesh: gmsh physical groups of the
    facet dimension (named through ``field_data``, unnamed ones by their number) and ``cell_sets``."""
    cells = m.cells_dict.get(facet)
    if cells is None:
        return {}
    dim = {c.facet: c.dim - 1 for c in CELL_TYPES}[facet]
    out = {}
    physical = m.cell_data_dict.get("gmsh:physical", {}).get(facet)
    if physical is not None:
        names = {int(v[0]): k for k, v in m.field_data.items() if len(v) > 1 and int(v[1]) == dim}
        for tag in np.unique(physical):
            out[names.get(int(tag), str(int(tag)))] = cells[physical == tag]
    for name, sets in m.cell_sets_dict.items():
        if facet in sets and not name.startswith("gmsh:"):
            out[name] = cells[np.asarray(sets[facet], dtype=int)]
    return out


def _facets_of(mesh, tags: dict[str, np.ndarray], path: str) -> dict[str, np.ndarray]:
    """Facet indices of ``mesh`` for each named set of node tuples; refuses tuples that are not facets."""
    kind = cell_type(mesh)
    facets = np.sort(mesh.facets.T, axis=1)
    out = {}
    for name, nodes in tags.items():
        nodes = np.sort(np.asarray(nodes).reshape(len(nodes), -1), axis=1)
        _, inv = np.unique(np.vstack([facets, nodes]), axis=0, return_inverse=True)
        inv = inv.ravel()
        where = np.full(inv.max() + 1, -1)
        where[inv[:len(facets)]] = np.arange(len(facets))
        hit = where[inv[len(facets):]]
        if (hit < 0).any():  # also tuples with a node no cell uses (index -1)
            raise ValueError(
                f"mesh file {path!r}: boundary tag {name!r} has {int((hit < 0).sum())} of {len(nodes)} "
                f"{kind.facet} cells that are not {kind.facet_word} of the {kind.cell} cells; "
                f"expected tagged {kind.facet} cells on the mesh's {kind.facet_word}"
            )
        out[name] = np.unique(hit)
    return out


def points_3d(mesh: skfem.Mesh) -> np.ndarray:
    """The vertices as meshio points ``(nvertices, 3)``, padded with zeros (gmsh and ParaView
    read three coordinates; meshio's gmsh writer would repeat a lone x into y and z)."""
    p = mesh.p.T
    return np.c_[p, np.zeros((p.shape[0], 3 - p.shape[1]))]


def save(path: str | os.PathLike, mesh: skfem.Mesh, point_data: dict | None = None) -> None:
    """Write ``mesh`` (and nodal fields) with meshio; the format follows the suffix.

    A ``.msh`` file is written as gmsh 2.2 and keeps the mesh's named boundaries as
    physical groups 1, 2, ... of its facet cells (the cells form the last group, named
    ``domain``); other formats keep the geometry and ``point_data`` only. A mesh class
    outside :data:`CELL_TYPES` is refused before anything is written.
    """
    import meshio

    kind = cell_type(mesh)
    path = os.fspath(path)
    if not path.endswith(".msh"):
        meshio.write(path, meshio.Mesh(points_3d(mesh), [(kind.cell, mesh.t.T)], point_data=point_data or {}))
        return
    named = dict(mesh.boundaries or {})
    cells = [(kind.cell, mesh.t.T)] + [(kind.facet, mesh.facets[:, np.asarray(f)].T) for f in named.values()]
    groups = [np.full(mesh.t.shape[1], len(named) + 1)]
    groups += [np.full(len(f), i) for i, f in enumerate(named.values(), start=1)]
    field = {name: np.array([i, kind.dim - 1]) for i, name in enumerate(named, start=1)}
    field["domain"] = np.array([len(named) + 1, kind.dim])
    meshio.write(path, meshio.Mesh(points_3d(mesh), cells, point_data=point_data or {},
                                   cell_data={"gmsh:physical": groups, "gmsh:geometrical": groups},
                                   field_data=field), file_format="gmsh22", binary=True)
