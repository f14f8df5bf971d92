"""Pictures of fields on the mesh: true vs predicted vs error (matplotlib).

2-D meshes: ``tripcolor`` with Gouraud shading; true and predicted share one
colour scale so they can be compared by eye, the error has its own symmetric
scale. 3-D (tetra) meshes: the same three panels on each of the three axis-aligned
mid-planes of the bounding box (:func:`mid_slice`: the exact cut of the piecewise-linear
field, so holes such as a cavity show as holes). 1-D meshes: true and predicted as
lines, the error on its own axis.
Input is what :func:`pdeinv.io.export.read_fields` returns, so a picture can be
made from a run directory alone (``pdeinv show DIR``).
"""

from __future__ import annotations

import numpy as np


def _pyplot():
    # the backend is the caller's choice: the CLI selects Agg, notebooks keep their inline one
    import matplotlib.pyplot as plt

    return plt


#: the sign-change edges of a tetrahedron, as pairs of its local vertices
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


def mid_slice(points, cells, axis: int):
    """Cut of a tetra mesh by the plane ``x_axis = c`` through the middle of its bounding box.

    The piecewise-linear field restricted to a plane is piecewise linear on the polygons
    where the plane cuts the cells (triangles and quadrilaterals, the quads split in two):
    each cut point lies on an edge ``(a, b)`` at ``t = d_a/(d_a − d_b)`` (``d`` the signed
    distances to the plane), and its value is ``(1−t) u_a + t u_b``. The plane is moved by
    1e-7 of the box so that no vertex lies on it. Returns ``(xy (m, 2), triangles (k, 3),
    W (m, nv))``: in-plane coordinates, triangles of the cut, and the sparse map from vertex
    values to values at the cut points (a field ``u (B, nv)`` is ``u @ W.T`` there).
    """
    import scipy.sparse as sp

    lo, hi = points.min(axis=0), points.max(axis=0)
    d = points[:, axis] - (0.5 * (lo[axis] + hi[axis]) + 1e-7 * (hi[axis] - lo[axis]))
    ends = cells[:, TET_EDGES]  # (ne, 6, 2)
    da, db = d[ends[..., 0]], d[ends[..., 1]]
    cut = da * db < 0
    count = cut.sum(axis=1)
    t = np.where(cut, da / np.where(cut, da - db, 1.0), 0.0)
    cells_cut = np.flatnonzero(count >= 3)
    e_cell, e_edge = np.nonzero(cut[cells_cut])  # row-major: a cell's cut edges are contiguous
    a, b = ends[cells_cut[e_cell], e_edge].T
    tt = t[cells_cut[e_cell], e_edge]
    m = len(tt)
    W = sp.csr_matrix((np.r_[1 - tt, tt], (np.r_[np.arange(m), np.arange(m)], np.r_[a, b])),
                      shape=(m, len(points)))
    xy = (W @ points)[:, [k for k in range(3) if k != axis]]
    start = np.r_[0, np.cumsum(count[cells_cut])[:-1]]
    tris = [np.c_[start, start + 1, start + 2][count[cells_cut] == 3]]
    quad = start[count[cells_cut] == 4][:, None] + np.arange(4)  # (q, 4) cut points, unordered
    if len(quad):
        rel = xy[quad] - xy[quad].mean(axis=1, keepdims=True)
        quad = np.take_along_axis(quad, np.argsort(np.arctan2(rel[..., 1], rel[..., 0]), axis=1), axis=1)
        tris += [quad[:, [0, 1, 2]], quad[:, [0, 2, 3]]]
    return xy, np.concatenate(tris), W


def _plot_slices(plt, points, cells, true, pred, err, rows):
    """3-D: one row per (sample, mid-plane), panels true | predicted | error on the cut; one
    colour bar per sample for true and predicted (shared scale) and one for the error.
    A fixed layout: constrained layout took 3 of the 6 s of a 27-panel picture."""
    from matplotlib.tri import Triangulation

    cuts = [mid_slice(points, cells, axis) for axis in range(3)]
    tris = [Triangulation(xy[:, 0], xy[:, 1], t) for xy, t, _ in cuts]
    fig = plt.figure(figsize=(8.5, 2.5 * 3 * len(rows)))
    grid = fig.add_gridspec(3 * len(rows), 6, width_ratios=[1, 1, 0.06, 0.3, 1, 0.06], left=0.07, right=0.93,
                            bottom=0.03, top=1 - 0.12 / len(rows), hspace=0.4, wspace=0.35)
    panel = {0: 0, 1: 1, 2: 4}  # grid column of true, predicted, error (2, 5: colour bars; 3: space)
    names = "xyz"
    for r, k in enumerate(rows):
        lim = float(np.abs(np.r_[true[k], pred[k]]).max()) or 1.0
        elim = float(np.abs(err[k]).max()) or 1.0
        images = {}
        for axis, ((xy, _, W), tri) in enumerate(zip(cuts, tris)):
            u, v = (names[i] for i in range(3) if i != axis)
            at = 0.5 * (points[:, axis].min() + points[:, axis].max())
            for c, (name, f, vmax, cmap) in enumerate((("true", true[k], lim, "RdBu_r"),
                                                       ("predicted", pred[k], lim, "RdBu_r"),
                                                       ("error", err[k], elim, "PuOr_r"))):
                ax = fig.add_subplot(grid[3 * r + axis, panel[c]])
                im = ax.tripcolor(tri, W @ f, shading="gouraud", cmap=cmap, vmin=-vmax, vmax=vmax)
                ax.set_aspect("equal")
                ax.tick_params(labelsize=6)
                ax.set_xlabel(u, fontsize=7, labelpad=1)
                ax.set_ylabel(v, fontsize=7, labelpad=1)
                ax.set_title(f"sample {k}, {names[axis]} = {at:.3g}: {name}" if c == 0 else name, fontsize=8)
                images[c] = im
        for c, col in ((0, 2), (2, 5)):
            bar = fig.colorbar(images[c], cax=fig.add_subplot(grid[3 * r:3 * r + 3, col]))
            bar.ax.tick_params(labelsize=7)
    return fig


def _rows(samples) -> list[int]:
    """``samples`` (an index or indices) as a list of ints; anything else a ``TypeError`` naming it."""
    if isinstance(samples, (int, np.integer)) and not isinstance(samples, bool):
        return [int(samples)]
    try:
        rows = list(samples)
    except TypeError:
        rows = None
    if rows is None or not all(isinstance(k, (int, np.integer)) and not isinstance(k, bool) for k in rows):
        raise TypeError(f"samples={samples!r:.60} is not allowed; expected None (all), an index or a list of "
                        "indices, e.g. [0, 2]")
    return [int(k) for k in rows]


def plot_fields(points, cells, fields: dict, samples=None, title: str = "", sensors=None):
    """Figure with one row per sample: x_true | x_pred | x_error (2-D), lines (1-D), or
    three rows per sample, one per mid-plane slice (3-D, :func:`mid_slice`).

    ``points`` ``(nv, ≥dim)``, ``cells`` ``(ne, 4)`` tetrahedra, ``(ne, 3)`` triangles or ``(ne, 2)`` lines,
    ``fields`` ``{"x_true": (B, nv), "x_pred": ..., "x_error": ...}`` and, from a calibrated run,
    ``"x_lo"``, ``"x_hi"`` (the credible band, shaded on the 1-D error panel) and ``"x_outside"``
    (nodes whose truth lies outside it, dotted on the 2-D error panel); ``sensors``
    ``(n, dim)`` coordinates are drawn as black dots on every panel (1-D and 2-D). Axes keep their ticks
    (domain coordinates).
    """
    plt = _pyplot()
    B = len(fields["x_true"])
    rows = list(range(B)) if samples is None else _rows(samples)
    bad = [k for k in rows if not 0 <= k < B]
    if B == 0:
        raise ValueError("the fields hold no samples (0 rows); expected at least one to draw")
    if bad or not rows:
        shown = samples if isinstance(samples, (int, np.integer)) else rows
        raise ValueError(f"samples={shown!r} is not allowed; the file holds samples 0..{B - 1}")
    true, pred = fields["x_true"], fields["x_pred"]
    err = fields.get("x_error", pred - true)
    if cells.shape[1] not in (2, 3, 4):
        raise ValueError(f"cells of {cells.shape[1]} nodes have no picture here; expected line, "
                         "triangle or tetra cells; open the fields file in ParaView instead")
    one_d = cells.shape[1] == 2
    if cells.shape[1] == 4:
        fig = _plot_slices(plt, np.asarray(points, dtype=float), cells, true, pred, err, rows)
    elif one_d:
        fig = _plot_lines(plt, points, true, pred, err, rows, fields)
    else:
        fig = _plot_triangles(plt, points, cells, true, pred, err, rows, sensors, fields.get("x_outside"))
    if title:
        fig.suptitle(title)
    return fig


def _plot_lines(plt, points, true, pred, err, rows, fields):
    """1-D: true and predicted over x, and the error (with the credible band around it), one row per
    sample."""
    fig, axes = plt.subplots(len(rows), 2, figsize=(9, 2.6 * len(rows)), squeeze=False,
                             layout="constrained")
    order = np.argsort(points[:, 0])
    x = points[order, 0]
    for r, k in enumerate(rows):
        a, b = axes[r]
        a.plot(x, true[k, order], "k-", lw=1.5, label="true")
        a.plot(x, pred[k, order], "C1--", lw=1.5, label="predicted")
        a.set(ylabel=f"sample {k}", xlabel="x")
        a.legend(fontsize=8)
        b.plot(x, err[k, order], "C3-", lw=1)
        if "x_lo" in fields and "x_hi" in fields:  # the interval around the estimate, as an error band
            p = pred[k, order]
            b.fill_between(x, fields["x_lo"][k, order] - p, fields["x_hi"][k, order] - p, color="C0",
                           alpha=0.2, lw=0, label="interval − predicted")
            b.legend(fontsize=8)
        b.axhline(0, color="0.7", lw=0.5)
        b.set(title="error" if r == 0 else "", xlabel="x")
    return fig


def _plot_triangles(plt, points, cells, true, pred, err, rows, sensors, outside=None):
    """2-D: true | predicted | error on the triangulation, one row per sample, sensors as dots; the
    nodes whose truth lies outside the credible interval (``outside`` ≠ 0) as dots on the error."""
    from matplotlib.tri import Triangulation

    tri = Triangulation(points[:, 0], points[:, 1], cells)
    fig, axes = plt.subplots(len(rows), 3, figsize=(10, 3.1 * len(rows)), squeeze=False,
                             layout="constrained")
    for r, k in enumerate(rows):
        lim = float(np.abs(np.r_[true[k], pred[k]]).max()) or 1.0
        elim = float(np.abs(err[k]).max()) or 1.0
        for c, (name, v, vmax, cmap) in enumerate((("true", true[k], lim, "RdBu_r"),
                                                   ("predicted", pred[k], lim, "RdBu_r"),
                                                   ("error", err[k], elim, "PuOr_r"))):
            ax = axes[r, c]
            im = ax.tripcolor(tri, v, shading="gouraud", cmap=cmap, vmin=-vmax, vmax=vmax)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
            if sensors is not None and len(sensors):
                s = np.asarray(sensors, dtype=float).reshape(len(sensors), -1)
                ax.plot(s[:, 0], s[:, 1], "k.", ms=3, label="sensors")
            if c == 2 and outside is not None:
                out = outside[k] != 0
                ax.plot(points[out, 0], points[out, 1], "k.", ms=1.5)
                name = f"error ({out.mean():.0%} outside the interval: dots)"
            ax.set_title(f"sample {k}: {name}" if c == 0 else name, fontsize=9)
            fig.colorbar(im, ax=ax, shrink=0.8)
    return fig


#: at most this many samples in a picture file (``fields.vtu`` keeps them all): 100 000 exported samples
#: once made a 900 × 35 712 px ``fields.png`` in 148 s
PNG_SAMPLES = 8


def save_fields_png(path, points, cells, fields: dict, samples=None, title: str = "", dpi: int = 90):
    """:func:`plot_fields` written to ``path`` (PNG); returns the path. Without ``samples``, the first
    :data:`PNG_SAMPLES` (named in the title when there are more)."""
    plt = _pyplot()
    B = len(fields["x_true"])
    if samples is None and B > PNG_SAMPLES:
        samples = range(PNG_SAMPLES)
        title = f"{title} (the first {PNG_SAMPLES} of {B} samples)".strip()
    fig = plot_fields(points, cells, fields, samples=samples, title=title)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def plot_prediction(problem, x_true, x_pred, samples=None, title: str = ""):
    """:func:`plot_fields` for free-unknown fields ``(B, N)`` of ``problem`` (no file needed),
    with the problem's sensors (``settings["sensor_points"]``) when it has any. ``x_true`` and ``x_pred``
    must have the same shape, ``(B, problem.N)`` or ``(problem.N,)``."""
    from .._checks import batch

    x_true, _ = batch(x_true, problem.N, "x_true")
    x_pred, _ = batch(x_pred, problem.N, "x_pred")
    if x_true.shape != x_pred.shape:
        raise ValueError(f"x_true has shape {x_true.shape} but x_pred has {x_pred.shape}; expected the same "
                         "samples of both")
    mesh = problem.disc.basis.mesh
    fields = {"x_true": problem.disc.vertex_values(x_true), "x_pred": problem.disc.vertex_values(x_pred)}
    return plot_fields(mesh.p.T, mesh.t.T, fields, samples=samples, title=title,
                       sensors=problem.settings.get("sensor_points"))
