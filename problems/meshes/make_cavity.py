"""Make ``cavity.msh``: the unit cube with an off-centre spherical cavity (run from anywhere).

    .venv/bin/python problems/meshes/make_cavity.py

Construction (no gmsh needed), the 3-D version of ``make_plate.py``'s spider web: the
cube's surface is triangulated as the boundary of scikit-fem's structured tetra mesh
(``N_SIDE`` squares per edge, two triangles each); every surface node ``q`` is joined by a
straight ray to the sphere point ``C + R (q − C)/|q − C|`` seen at the same angle from the
centre ``C``; ``N_RADIAL`` layers along each ray, graded toward the cavity
(``s = (j/N_RADIAL)^GRADING``). Each surface triangle sweeps a column of prisms, and each
prism is cut into three tetrahedra by the minimum-index rule of Dompierre, Labbé, Vallet
and Camarero ("How to subdivide pyramids, prisms and hexahedra into tetrahedra", 1999):
every quadrilateral face is split along the diagonal through its lowest global node
number, so neighbouring prisms cut their shared face the same way and the mesh is
conforming. The cavity is a polyhedron with the cube surface's ``6 N_SIDE² + 2`` vertices,
all on the sphere; uniform refinement (``mesh.refined()``) keeps that polyhedron.
Off-centre, so no symmetry hides an indexing error.

The file is gmsh 2.2 with two named boundaries (physical surface groups), found by
geometry here: ``outer`` (the cube's faces) and ``cavity`` (the sphere).
"""

from pathlib import Path

import numpy as np
import skfem

from pdeinv import mesh as pmesh

CENTER, RADIUS = np.array([0.45, 0.55, 0.5]), 0.25
N_SIDE, N_RADIAL, GRADING = 6, 5, 1.3

#: vertex permutations of a prism (bottom 0 1 2, top 3 4 5 above them) that bring vertex k to 0
PRISM_TURN = np.array([[0, 1, 2, 3, 4, 5], [1, 2, 0, 4, 5, 3], [2, 0, 1, 5, 3, 4],
                       [3, 5, 4, 0, 2, 1], [4, 3, 5, 1, 0, 2], [5, 4, 3, 2, 1, 0]])


def prisms_to_tets(prisms: np.ndarray) -> np.ndarray:
    """``(n, 6)`` prisms -> ``(3n, 4)`` tetrahedra by the minimum-index rule (see the module doc)."""
    v = np.take_along_axis(prisms, PRISM_TURN[np.argmin(prisms, axis=1)], axis=1)
    first = np.minimum(v[:, 1], v[:, 5]) < np.minimum(v[:, 2], v[:, 4])  # diagonal 1–5, else 2–4
    a = v[:, [0, 1, 2, 5, 0, 1, 5, 4, 0, 4, 5, 3]].reshape(-1, 3, 4)
    b = v[:, [0, 1, 2, 4, 0, 4, 2, 5, 0, 4, 5, 3]].reshape(-1, 3, 4)
    return np.where(first[:, None, None], a, b).reshape(-1, 4)


def cube_surface(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes ``(m, 3)`` and triangles ``(k, 3)`` of the unit cube's surface, ``n`` squares per edge."""
    x = np.linspace(0.0, 1.0, n + 1)
    box = skfem.MeshTet.init_tensor(x, x, x)
    tris = box.facets[:, box.boundary_facets()].T
    nodes, tris = np.unique(tris, return_inverse=True)
    return box.p[:, nodes].T, tris.reshape(-1, 3)


def cavity() -> skfem.MeshTet:
    outer, tris = cube_surface(N_SIDE)
    direction = (outer - CENTER) / np.linalg.norm(outer - CENTER, axis=1)[:, None]
    inner = CENTER + RADIUS * direction
    s = (np.arange(N_RADIAL + 1) / N_RADIAL) ** GRADING
    pts = (1 - s)[:, None, None] * inner[None] + s[:, None, None] * outer[None]  # (layer, node, 3)
    m = len(outer)
    prisms = np.concatenate([np.c_[tris + j * m, tris + (j + 1) * m] for j in range(N_RADIAL)])
    t = prisms_to_tets(prisms)
    mesh = skfem.MeshTet(np.ascontiguousarray(pts.reshape(-1, 3).T), np.ascontiguousarray(t.T))
    on_cube = lambda x: np.isclose(np.max(np.abs(x - 0.5), axis=0), 0.5)  # noqa: E731
    return mesh.with_boundaries({"outer": on_cube, "cavity": lambda x: ~on_cube(x)})


if __name__ == "__main__":
    m = cavity()
    out = Path(__file__).with_name("cavity.msh")
    pmesh.save(out, m)
    sizes = ", ".join(f"{k}: {len(v)} triangles" for k, v in m.boundaries.items())
    print(f"wrote {out}: {m.p.shape[1]} nodes, {m.t.shape[1]} tetrahedra; boundaries {sizes}; "
          f"{out.stat().st_size / 1e3:.0f} kB")
