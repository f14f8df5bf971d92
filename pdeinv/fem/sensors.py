"""Point sensors: the sensor matrix ``S`` and where to put the sensors.

A sensor at ``p`` reads the finite-element field there, ``u_h(p) = Σ_j u_j φ_j(p)``,
so a set of sensors is the sparse matrix ``S_kj = φ_j(p_k)`` (scikit-fem's
``basis.probes``) restricted to the free unknowns ``disc.free``: Dirichlet
unknowns are zero, so dropping their columns is exact. A sensor on a Dirichlet
boundary would always read 0 and is refused.

Placement helpers return coordinates of shape ``(n, dim)``:

* :func:`boundary_points` — ``n`` points evenly spaced by arc length along the
  mesh boundary (2-D, all boundary loops) or spread over the boundary faces (3-D,
  farthest-point sampling), optionally moved ``inset`` inward;
* :func:`place` — either of the two for a count, or given coordinates as they are;
* :func:`interior_points` — ``n`` well-spread points inside the mesh (Halton
  sequence over the bounding box, 2-D or 3-D, kept if inside and at least ``margin``
  from the bounding box's edge).

:func:`sensor_spec` is the settings rule for a ``sensors`` override: an int count
or coordinates (a list/array of shape ``(n, dim)``, or its string form from ``--set``).
"""

from __future__ import annotations

import ast
from numbers import Integral

import numpy as np
import scipy.sparse as sp

from .._checks import count


def _as_points(points, dim: int) -> np.ndarray:
    """Coordinates as a float64 ``(n, dim)`` array, or a ValueError saying what is allowed."""
    try:
        P = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(
            f"sensors={points!r} is not allowed; expected coordinates of shape (n, {dim})"
        ) from None
    if dim == 1 and P.ndim == 1:
        P = P[:, None]
    if P.ndim != 2 or P.shape[1] != dim:
        raise ValueError(f"sensor coordinates have shape {P.shape}; expected (n, {dim}) with n >= 1")
    if P.shape[0] == 0:
        raise ValueError(f"the sensor list is empty (shape {P.shape}); expected at least one sensor")
    if not np.isfinite(P).all():
        raise ValueError(f"sensor coordinates contain NaN or Inf: {P[~np.isfinite(P).all(1)][:3].tolist()}")
    return P


#: points per call of scikit-fem's element finder and probes: their temporaries grow like points ×
#: candidate cells (5.45 GiB for one array at 10⁶ sensors on wave_sensors_2d), so a long sensor list
#: goes through in chunks of bounded memory
CHUNK = 4096


def _chunks(P: np.ndarray):
    return (P[i:i + CHUNK] for i in range(0, len(P), CHUNK))


def outside(mesh, points) -> np.ndarray:
    """Indices of the ``points`` (``(n, dim)``) that lie outside ``mesh`` (the element finder's test)."""
    P = _as_points(points, mesh.dim())
    finder = mesh.element_finder()
    bad = []
    for start, chunk in zip(range(0, len(P), CHUNK), _chunks(P)):
        try:
            finder(*chunk.T)
            continue
        except ValueError:  # the finder refuses the whole chunk: find the culprits one by one
            pass
        for k, p in enumerate(chunk, start=start):
            try:
                finder(*p[:, None])
            except ValueError:
                bad.append(k)
    return np.asarray(bad, dtype=int)


def sensor_matrix(disc, points) -> sp.csr_matrix:
    """``S`` of shape ``(n_sensors, disc.N)``: point evaluation of the field on the free unknowns.

    Raises ``ValueError`` for an empty list, points outside the mesh, or points on
    the Dirichlet boundary (where every free basis function vanishes).
    """
    P = _as_points(points, disc.dim)
    bad = outside(disc.basis.mesh, P)
    if len(bad):
        lo, hi = disc.basis.mesh.p.min(axis=1), disc.basis.mesh.p.max(axis=1)
        raise ValueError(
            f"{len(bad)} sensor(s) lie outside the mesh, e.g. sensor {bad[0]} at "
            f"{P[bad[0]].tolist()}; allowed: points inside the domain "
            f"(bounding box {lo.tolist()} – {hi.tolist()})"
        )
    S = sp.vstack([sp.csr_matrix(disc.basis.probes(c.T)) for c in _chunks(P)], format="csr")[:, disc.free]
    dead = np.flatnonzero(np.abs(S).sum(axis=1).A1 == 0)
    if len(dead):
        many = (f"; {len(P)} sensors on a mesh of {len(disc.free)} unknowns see at most {len(disc.free)} "
                "independent values: fewer sensors, or a finer mesh") if len(P) > len(disc.free) else ""
        raise ValueError(
            f"sensor {dead[0]} at {P[dead[0]].tolist()} lies where the field is fixed at 0 (on the "
            f"Dirichlet boundary, or in an element whose nodes all lie on it; {len(dead)} such sensor(s)); "
            "allowed: points where the field is free — move it inside (e.g. boundary_points(mesh, n, "
            f"inset=h)), refine the mesh, or make that boundary natural (Neumann){many}"
        )
    S.eliminate_zeros()
    return S


# -- placement -----------------------------------------------------------------------------


def boundary_loops(mesh) -> list[np.ndarray]:
    """Closed boundary polygons of a 2-D mesh as node-index arrays, each counter-clockwise
    around the domain on its left (outer loop CCW, holes CW)."""
    facets = mesh.boundary_facets()
    edges = mesh.facets[:, facets].T.copy()
    # orient every edge with the domain on its left: the opposite vertex must be to the left
    tri = mesh.f2t[0, facets]
    opp = mesh.t[:, tri].T
    other = np.array([np.setdiff1d(o, e)[0] for o, e in zip(opp, edges)])
    a, b, c = mesh.p[:, edges[:, 0]], mesh.p[:, edges[:, 1]], mesh.p[:, other]
    cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    edges[cross < 0] = edges[cross < 0, ::-1]
    nxt = dict(zip(edges[:, 0], edges[:, 1]))
    loops, seen = [], set()
    for start in edges[:, 0]:
        if start in seen:
            continue
        loop, n = [start], nxt[start]
        seen.add(start)
        while n != start:
            loop.append(n)
            seen.add(n)
            n = nxt[n]
        loops.append(np.asarray(loop))
    return loops


def boundary_points(mesh, n: int, inset: float = 0.0) -> np.ndarray:
    """``n`` well-spread points on the boundary of a 2-D (:func:`_along_loops`) or 3-D
    (:func:`_over_faces`) mesh, moved ``inset`` inward (``inset=0``: on the boundary, for
    natural boundaries; ``inset ≈ h`` for Dirichlet ones)."""
    n = count(n, "sensors")
    if mesh.dim() not in ON_BOUNDARY:
        raise ValueError(f"boundary_points needs a 2-D or 3-D mesh; got dim={mesh.dim()}")
    if not (np.isfinite(inset) and inset >= 0):
        raise ValueError(f"inset={inset!r} is not allowed; expected a finite number >= 0")
    return ON_BOUNDARY[mesh.dim()](mesh, n, inset)


def _along_loops(mesh, n: int, inset: float) -> np.ndarray:
    """2-D: ``n`` points at equal arc-length spacing along the whole boundary.

    Point ``k`` sits at arc length ``(k + ½) L/n`` of the concatenated boundary
    loops (total length ``L``), moved ``inset`` inward (``inset=0``: on the
    boundary, for natural boundaries; ``inset ≈ h`` for Dirichlet ones). The
    move is interpolated along each edge between *vertex offsets*
    ``o = inset (n₁ + n₂)/(1 + n₁·n₂)`` (``n₁, n₂`` the unit inward normals of the
    two edges meeting there), so every moved point is exactly ``inset`` from the
    line of its own edge, and a point at a corner is ``inset`` from both edges
    instead of sliding along the neighbouring one (which, on a Dirichlet
    boundary, would leave it reading 0).
    """
    starts, ends, offs_a, offs_b = [], [], [], []
    for loop in boundary_loops(mesh):
        a, b = mesh.p[:, loop].T, mesh.p[:, np.roll(loop, -1)].T
        tangent = (b - a) / np.linalg.norm(b - a, axis=1)[:, None]
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)  # domain on the left
        prev = np.roll(normal, 1, axis=0)  # the edge ending at vertex a
        cos = np.einsum("ij,ij->i", prev, normal)
        vertex = inset * (prev + normal) / np.maximum(1.0 + cos, 0.1)[:, None]  # offset at vertex a
        starts.append(a)
        ends.append(b)
        offs_a.append(vertex)
        offs_b.append(np.roll(vertex, -1, axis=0))
    a, b = np.concatenate(starts), np.concatenate(ends)
    oa, ob = np.concatenate(offs_a), np.concatenate(offs_b)
    length = np.linalg.norm(b - a, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s = (np.arange(n) + 0.5) * cum[-1] / n
    e = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(a) - 1)
    t = ((s - cum[e]) / length[e])[:, None]
    return a[e] + t * (b[e] - a[e]) + (1 - t) * oa[e] + t * ob[e]


def _inward_faces(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Boundary triangles ``(F, 3)`` (vertex indices) of a tetra mesh and their inward unit normals."""
    facets = mesh.boundary_facets()
    tri = mesh.facets[:, facets].T
    a, b, c = (mesh.p[:, tri[:, k]].T for k in range(3))
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    inside = mesh.p[:, mesh.t[:, mesh.f2t[0, facets]]].mean(axis=1).T - a  # toward the cell's centroid
    normal *= np.sign(np.einsum("ij,ij->i", normal, inside))[:, None]
    return tri, normal


def _over_faces(mesh, n: int, inset: float) -> np.ndarray:
    """3-D: ``n`` points on the boundary faces, spread by farthest-point sampling.

    Candidates are the centroids of each boundary triangle cut into ``m²`` sub-triangles
    (``m`` so that there are ≥ 8n candidates); starting from the one nearest the bounding
    box's lowest corner, each next point is the candidate farthest from those already taken.
    The inward move mirrors the 2-D rule: every boundary vertex moves by
    ``o = inset n_v / min_f(n_v·n_f)`` (``n_v`` the normalized sum of the unit inward normals
    ``n_f`` of its faces), the move is interpolated linearly over each face, so every point
    is at least ``inset`` from the planes of the faces at its triangle's vertices — also at
    an edge or a corner of the boundary, where a move along one face's normal would leave
    it on the neighbouring (possibly Dirichlet) face. ``inset=0`` still moves them 1e-9 of the
    box's diagonal inward: a point computed on a slanted face can round to just outside it.
    """
    inset = max(inset, 1e-9 * float(np.linalg.norm(np.ptp(mesh.p, axis=1))))
    tri, normal = _inward_faces(mesh)
    nv = np.zeros_like(mesh.p.T)
    np.add.at(nv, tri.ravel(), np.repeat(normal, 3, axis=0))
    nv /= np.maximum(np.linalg.norm(nv, axis=1), 1e-300)[:, None]
    low = np.full(len(nv), np.inf)
    np.minimum.at(low, tri.ravel(), np.einsum("ij,ij->i", nv[tri.ravel()], np.repeat(normal, 3, axis=0)))
    moved = mesh.p.T + inset * nv / np.maximum(low, 0.1)[:, None]
    m = int(np.ceil(np.sqrt(8 * n / len(tri))))
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    up = np.c_[i[i + j <= m - 1] + 1 / 3, j[i + j <= m - 1] + 1 / 3]
    down = np.c_[i[i + j <= m - 2] + 2 / 3, j[i + j <= m - 2] + 2 / 3]
    st = np.vstack([up, down]) / m  # (m², 2) barycentric coordinates of vertices 1 and 2
    bary = np.c_[1 - st.sum(axis=1), st]
    cand = np.einsum("sk,fkd->fsd", bary, moved[tri]).reshape(-1, 3)
    return _farthest(cand, n)


def _farthest(cand: np.ndarray, n: int) -> np.ndarray:
    """``n`` of the candidate points ``(C, dim)`` by greedy farthest-point sampling (deterministic)."""
    take = [int(np.argmin((cand - cand.min(axis=0)).sum(axis=1)))]
    dist = np.linalg.norm(cand - cand[take[0]], axis=1)
    for _ in range(n - 1):
        take.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(cand - cand[take[-1]], axis=1))
    return cand[take]


#: boundary placement by mesh dimension
ON_BOUNDARY = {2: _along_loops, 3: _over_faces}


def _halton(n: int, base: int) -> np.ndarray:
    out = np.zeros(n)
    for i in range(n):
        f, k, x = 1.0, i + 1, 0.0
        while k:
            f /= base
            x += f * (k % base)
            k //= base
        out[i] = x
    return out


def interior_points(mesh, n: int, margin: float = 0.1) -> np.ndarray:
    """``n`` deterministic, well-spread points inside ``mesh`` (Halton sequence, bases 2, 3, 5).

    Candidates fill the bounding box shrunk by ``margin`` (a fraction of its size)
    on each side; those outside the mesh (holes, re-entrant corners) are skipped.
    """
    n = count(n, "sensors")
    lo, hi = mesh.p.min(axis=1), mesh.p.max(axis=1)
    lo, hi = lo + margin * (hi - lo), hi - margin * (hi - lo)
    found, m = np.zeros((0, len(lo))), 0
    while len(found) < n:
        m = max(2 * m, 2 * n)
        cand = lo + (hi - lo) * np.stack([_halton(m, b) for b in (2, 3, 5)[:len(lo)]], axis=1)
        bad = outside(mesh, cand)
        found = np.delete(cand, bad, axis=0)
        if m > 1000 * n:
            raise ValueError(f"could not place {n} sensors inside the mesh (margin={margin})")
    return found[:n]


#: bytes per sensor while placing, locating and probing in chunks of :data:`CHUNK` (see :func:`place`)
SENSOR_BYTES = 2_000


def place(mesh, spec, where: str = "boundary", inset: float = 0.0) -> np.ndarray:
    """Coordinates ``(n, dim)`` from a :func:`sensor_spec` value: a count is placed by
    :func:`boundary_points` (``where='boundary'``, moved ``inset`` inward) or
    :func:`interior_points` (``where='inside'``); coordinates pass through. Refused first
    (:mod:`pdeinv.util.memory`) when the sensors would not fit: ~2 kB per sensor to place, locate
    and probe them in chunks (10⁶ boundary sensors on wave_sensors_2d peak at 0.23 GB)."""
    from ..util import memory

    n = int(spec) if isinstance(spec, Integral) else len(spec)
    memory.check(SENSOR_BYTES * n, f"{n} sensors", "use fewer sensors")
    if isinstance(spec, Integral) and not isinstance(spec, bool):
        if where == "boundary":
            return boundary_points(mesh, spec, inset=inset)
        if where == "inside":
            return interior_points(mesh, spec)
        raise ValueError(f"where={where!r} is not allowed; expected 'boundary' or 'inside'")
    return _as_points(spec, mesh.dim())


def sensor_spec(value, name: str = "sensors"):
    """Settings rule: an int ``>= 1`` (a count to place) or coordinates ``(n, dim)``, dim 1–3
    (checked against the mesh's dimension by :func:`place`).

    Strings from ``--set`` are parsed: ``"16"`` → 16, ``"[[0.5, 0.5], [0.2, 0.3]]"``
    → coordinates.
    """
    if isinstance(value, str):
        try:
            value = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            raise ValueError(f"{name}={value!r} is not allowed; expected an integer count >= 1 or "
                             "coordinates such as [[0.5, 0.5], [0.2, 0.3]]") from None
    if isinstance(value, bool):
        raise ValueError(f"{name}={value!r} is not allowed; expected an integer count >= 1 or coordinates")
    if isinstance(value, Integral):
        return count(value, name)
    if isinstance(value, float) and value.is_integer():
        return count(int(value), name)
    try:
        shape = np.shape(value)
    except ValueError:  # ragged lists: _as_points names them
        shape = ()
    dim = shape[1] if len(shape) == 2 and shape[1] in (1, 2, 3) else 2  # else: "expected (n, 2)"
    return _as_points(value, dim)
