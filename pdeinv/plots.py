"""Pictures of fields on the mesh: true vs predicted vs error (matplotlib).

2-D meshes: ``tripcolor`` with Gouraud shading; true and predicted share one
colour scale so they can be compared by eye, the error has its own symmetric
scale. 1-D meshes: true and predicted as lines, the error on its own axis.
Input is what :func:`pdeinv.export.read_fields` returns, so a picture can be
made from a run directory alone (``pdeinv show DIR``).
"""

from __future__ import annotations

import numpy as np


def _pyplot():
    # the backend is the caller's choice: the CLI selects Agg, notebooks keep their inline one
    import matplotlib.pyplot as plt

    return plt


def plot_fields(points, cells, fields: dict, samples=None, title: str = "", sensors=None):
    """Figure with one row per sample: x_true | x_pred | x_error (2-D) or lines (1-D).

    ``points`` ``(nv, ≥dim)``, ``cells`` ``(ne, 3)`` triangles or ``(ne, 2)`` lines,
    ``fields`` ``{"x_true": (B, nv), "x_pred": ..., "x_error": ...}``; ``sensors``
    ``(n, dim)`` coordinates are drawn as black dots on every panel. Axes keep their ticks
    (domain coordinates).
    """
    plt = _pyplot()
    B = len(fields["x_true"])
    rows = list(range(B)) if samples is None else [int(k) for k in samples]
    bad = [k for k in rows if not 0 <= k < B]
    if bad or not rows:
        raise ValueError(f"samples={rows!r} is not allowed; the file holds samples 0..{B - 1}")
    true, pred = fields["x_true"], fields["x_pred"]
    err = fields.get("x_error", pred - true)
    if cells.shape[1] not in (2, 3):
        raise ValueError(f"cells of {cells.shape[1]} nodes (tetra: a 3-D mesh) have no picture here; "
                         "expected line or triangle cells; open the fields file in ParaView instead")
    one_d = cells.shape[1] == 2
    if one_d:
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
            b.axhline(0, color="0.7", lw=0.5)
            b.set(title="error" if r == 0 else "", xlabel="x")
    else:
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
                ax.set_title(f"sample {k}: {name}" if c == 0 else name, fontsize=9)
                fig.colorbar(im, ax=ax, shrink=0.8)
    if title:
        fig.suptitle(title)
    return fig


def save_fields_png(path, points, cells, fields: dict, samples=None, title: str = "", dpi: int = 90):
    """:func:`plot_fields` written to ``path`` (PNG); returns the path."""
    plt = _pyplot()
    fig = plot_fields(points, cells, fields, samples=samples, title=title)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def plot_prediction(problem, x_true, x_pred, samples=None, title: str = ""):
    """:func:`plot_fields` for free-unknown fields ``(B, N)`` of ``problem`` (no file needed),
    with the problem's sensors (``settings["sensor_points"]``) when it has any."""
    mesh = problem.disc.basis.mesh
    fields = {"x_true": problem.disc.vertex_values(np.atleast_2d(x_true)),
              "x_pred": problem.disc.vertex_values(np.atleast_2d(x_pred))}
    return plot_fields(mesh.p.T, mesh.t.T, fields, samples=samples, title=title,
                       sensors=problem.settings.get("sensor_points"))
