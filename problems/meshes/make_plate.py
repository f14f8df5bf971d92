"""Make ``plate.msh``: the unit-square plate with an off-centre circular hole (run from anywhere).

    .venv/bin/python problems/meshes/make_plate.py

Construction (no gmsh needed): a structured "spider web" between the hole and
the square. ``N_AROUND`` points equally spaced along the square's perimeter
(corners included) are joined by straight rays to the hole points at the same
angle seen from the hole centre; ``N_RADIAL`` layers along each ray, graded
toward the hole (``s = (j/N_RADIAL)^GRADING``), and each quad is split into two
triangles along its shorter diagonal. The hole is a polygon
with ``N_AROUND`` vertices; uniform refinement (``mesh.refined()``) keeps that
polygon. Off-centre, so no symmetry hides an indexing error.

The file is gmsh 2.2 with two named boundaries (physical line groups), found by
geometry here: ``outer`` (the square) and ``hole`` (the circle).
"""

from pathlib import Path

import numpy as np
import skfem

from pdeinv import mesh as pmesh

CENTER, RADIUS = np.array([0.42, 0.56]), 0.2
N_AROUND, N_RADIAL, GRADING = 64, 10, 1.3


def perimeter(n: int) -> np.ndarray:
    """``n`` points (a multiple of 4) equally spaced counter-clockwise on ∂[0,1]², from (0, 0)."""
    t = np.arange(n) * 4.0 / n
    side, u = np.divmod(t, 1.0)
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]], dtype=float)
    side = side.astype(int)
    return corners[side] + u[:, None] * (corners[side + 1] - corners[side])


def plate() -> skfem.MeshTri:
    outer = perimeter(N_AROUND)
    angle = np.arctan2(*(outer - CENTER).T[::-1])
    inner = CENTER + RADIUS * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    s = (np.arange(N_RADIAL + 1) / N_RADIAL) ** GRADING
    pts = (1 - s)[:, None, None] * inner[None] + s[:, None, None] * outer[None]  # (layer, around, 2)
    idx = np.arange(pts.shape[0] * N_AROUND).reshape(pts.shape[0], N_AROUND)
    tris = []
    for j in range(N_RADIAL):
        for i in range(N_AROUND):
            a, b = idx[j, i], idx[j, (i + 1) % N_AROUND]
            c, d = idx[j + 1, (i + 1) % N_AROUND], idx[j + 1, i]
            P = pts.reshape(-1, 2)
            if np.linalg.norm(P[a] - P[c]) <= np.linalg.norm(P[b] - P[d]):
                tris += [(a, b, c), (a, c, d)]
            else:
                tris += [(a, b, d), (b, c, d)]
    p = pts.reshape(-1, 2).T
    t = np.array(tris).T
    # orientation does not matter: scikit-fem sorts each triangle's nodes and uses |det J|
    m = skfem.MeshTri(np.ascontiguousarray(p), np.ascontiguousarray(t))
    on_square = lambda x: np.isclose(np.max(np.abs(x - 0.5), axis=0), 0.5)  # noqa: E731
    return m.with_boundaries({"outer": on_square, "hole": lambda x: ~on_square(x)})


if __name__ == "__main__":
    m = plate()
    out = Path(__file__).with_name("plate.msh")
    pmesh.save(out, m)
    sizes = ", ".join(f"{k}: {len(v)} edges" for k, v in m.boundaries.items())
    print(f"wrote {out}: {m.p.shape[1]} nodes, {m.t.shape[1]} triangles; boundaries {sizes}")
