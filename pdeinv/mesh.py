"""Meshes: built-in intervals and unit squares (scikit-fem) and files read with meshio.

Named boundaries travel with the mesh (``mesh.boundaries``: name -> facet
indices, kept by ``refined()``). Files carry them as tagged line cells: gmsh
physical groups (``gmsh:physical`` cell data named through ``field_data``) or
meshio ``cell_sets``; :func:`save` writes them back as gmsh 2.2 physical groups.
Dirichlet selection by name or by geometry lives in :mod:`pdeinv.forms`.
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
    used = np.unique(cells)
    index = np.full(len(pts), -1)
    index[used] = np.arange(len(used))  # drop nodes no cell uses (e.g. gmsh geometry points)
    mesh = _CELLS[kind](np.ascontiguousarray(pts[used].T), np.ascontiguousarray(index[cells].T))
    if kind != "triangle":
        return mesh
    tags = {name: index[pairs] for name, pairs in _line_tags(m).items()}
    return mesh.with_boundaries(_facets_of(mesh, tags, path)) if tags else mesh


def _line_tags(m) -> dict[str, np.ndarray]:
    """Named sets of line cells (node pairs) in a meshio mesh: gmsh physical groups of
    dimension 1 (named through ``field_data``, unnamed ones by their number) and ``cell_sets``."""
    lines = m.cells_dict.get("line")
    if lines is None:
        return {}
    out = {}
    physical = m.cell_data_dict.get("gmsh:physical", {}).get("line")
    if physical is not None:
        names = {int(v[0]): k for k, v in m.field_data.items() if len(v) > 1 and int(v[1]) == 1}
        for tag in np.unique(physical):
            out[names.get(int(tag), str(int(tag)))] = lines[physical == tag]
    for name, sets in m.cell_sets_dict.items():
        if "line" in sets and not name.startswith("gmsh:"):
            out[name] = lines[np.asarray(sets["line"], dtype=int)]
    return out


def _facets_of(mesh, tags: dict[str, np.ndarray], path: str) -> dict[str, np.ndarray]:
    """Facet indices of ``mesh`` for each named set of node pairs; refuses pairs that are not edges."""
    n = mesh.p.shape[1]
    f = np.sort(mesh.facets, axis=0)
    keys = f[0] * n + f[1]
    order = np.argsort(keys)
    out = {}
    for name, pairs in tags.items():
        p = np.sort(pairs, axis=1)
        want = np.where((p >= 0).all(axis=1), p[:, 0] * n + p[:, 1], -1)
        pos = np.clip(np.searchsorted(keys, want, sorter=order), 0, len(keys) - 1)
        hit = keys[order[pos]] == want
        if not hit.all():
            raise ValueError(
                f"mesh file {path!r}: boundary tag {name!r} has {int((~hit).sum())} of {len(p)} line "
                "cells that are not edges of the triangles; expected tagged lines on the mesh's edges"
            )
        out[name] = np.unique(order[pos])
    return out


def save(path: str | os.PathLike, mesh: skfem.Mesh, point_data: dict | None = None) -> None:
    """Write ``mesh`` (and nodal fields) with meshio; the format follows the suffix.

    A ``.msh`` file is written as gmsh 2.2 and keeps the mesh's named boundaries as
    physical line groups 1, 2, ... (the cells form the last group, named ``domain``);
    other formats keep the geometry and ``point_data`` only.
    """
    import meshio

    path = os.fspath(path)
    kind = "triangle" if mesh.dim() == 2 else "line"
    if not path.endswith(".msh"):
        meshio.write(path, meshio.Mesh(mesh.p.T, [(kind, mesh.t.T)], point_data=point_data or {}))
        return
    named = dict(mesh.boundaries or {}) if kind == "triangle" else {}
    cells = [(kind, mesh.t.T)] + [("line", mesh.facets[:, np.asarray(f)].T) for f in named.values()]
    groups = [np.full(mesh.t.shape[1], len(named) + 1)]
    groups += [np.full(len(f), i) for i, f in enumerate(named.values(), start=1)]
    field = {name: np.array([i, 1]) for i, name in enumerate(named, start=1)}
    field["domain"] = np.array([len(named) + 1, mesh.dim()])
    meshio.write(path, meshio.Mesh(mesh.p.T, cells, point_data=point_data or {},
                                   cell_data={"gmsh:physical": groups, "gmsh:geometrical": groups},
                                   field_data=field), file_format="gmsh22", binary=True)
