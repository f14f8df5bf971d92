"""Fields on the mesh for ParaView: true, predicted and error fields written with meshio.

A field of the free unknowns ``(N,)`` is extended by zero to the Dirichlet
unknowns (:meth:`pdeinv.fem.forms.Discretization.extend`) and restricted to the mesh
vertices (for P2 the vertex DOFs come first in scikit-fem's numbering, so the
vertex values are the first ``nvertices`` coefficients; edge midpoints are not
written). One file holds every array as point data, named

    x_true_<k>, x_pred_<k>, x_error_<k> = x_pred_<k> − x_true_<k>

for sample ``k`` (and ``y_obs_<k>``, ``y_pred_<k>`` when the observation is a
field on the mesh too, e.g. the final temperature). The suffix picks the
format: ``.vtu`` (one file) or ``.xdmf`` (XML + HDF5 needs h5py, so XDMF is
written with inline XML data). Sensor positions go to a separate vertex-cell file.
Cells are named through :data:`pdeinv.fem.mesh.CELL_TYPES` (line, triangle, tetra); a mesh
outside that table is refused. Pictures come from :mod:`pdeinv.io.plots` (3-D: mid-plane slices).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .._checks import batch, shown
from .._checks import problem as _problem
from ..fem.mesh import cell_type, points_3d
from ..physics.capabilities import observes_field
from .plots import save_fields_png

#: what :func:`write_fields` writes per sample, in order
KINDS = ("x_true", "x_pred", "x_error", "y_obs", "y_pred", "x_std", "x_lo", "x_hi", "x_outside")


def vertex_values(disc, X: np.ndarray) -> np.ndarray:
    """Free-unknown fields ``(B, N)`` -> values at the mesh vertices ``(B, nvertices)``
    (:meth:`pdeinv.fem.forms.Discretization.vertex_values`)."""
    return disc.vertex_values(X)


def _cells(mesh) -> list:
    """meshio cells of ``mesh`` through the one table :data:`pdeinv.fem.mesh.CELL_TYPES` (refuses others)."""
    return [(cell_type(mesh).cell, mesh.t.T)]


def write_fields(path, problem, x_true, x_pred, y_obs=None, y_pred=None, bars=None, *,
                 overwrite: bool = False) -> Path:
    """Write true/predicted/error initial fields (and field observations) of a few samples.

    ``path`` (``.vtu`` or ``.xdmf``) follows the output-path policy of ``pdeinv predict --vtu``
    (:func:`pdeinv.util.outpaths.output_file`): its folder is created; an existing file is replaced only
    with ``overwrite=True``, and a run folder's own files never.

    ``bars`` (:func:`pdeinv.posterior.predictive`'s ``{"std", "lo", "hi"}``, rows as ``x_pred``) adds
    ``x_std``, ``x_lo``, ``x_hi`` and, with ``x_true``, ``x_outside``: +1 where the truth lies above the
    interval, −1 below, 0 inside.

    ``x_*`` have shape ``(B, N)`` on the free unknowns; ``x_true=None`` (observations
    without true fields, e.g. ``pdeinv predict``) writes ``x_pred_<k>`` only. ``y_*`` are
    written only if the operator declares its observations fields on the mesh
    (:func:`pdeinv.physics.capabilities.observes_field`; sensor records are not). Returns the path.
    """
    from ..training.arguments import _kind, flag
    from ..util.outpaths import output_file

    if not isinstance(path, (str, os.PathLike)) or isinstance(os.fspath(path), bytes):
        raise TypeError(f"path={path!r:.60} is {_kind(path)}; expected the file to write (str or path, "
                        "ending in .vtu or .xdmf)")
    flag(overwrite, "overwrite")
    if Path(path).suffix not in (".vtu", ".xdmf"):
        raise ValueError(f"fields file {os.fspath(path)!r}: suffix {Path(path).suffix!r} is not allowed; "
                         "expected '.vtu' or '.xdmf'")
    data = _point_data(problem, x_true, x_pred, y_obs, y_pred, bars)  # checked before any folder is made
    return _write(output_file(path, "path", suffixes=(".vtu", ".xdmf"), overwrite=overwrite), problem, data)


def fields_file(path: Path, problem, x_true, x_pred, y_obs=None, y_pred=None, bars=None) -> Path:
    """:func:`write_fields` into ``path`` as it is: for a caller that applied the output-path policy
    itself (``pdeinv train`` into its run folder, ``pdeinv predict --vtu``)."""
    return _write(Path(path), problem, _point_data(problem, x_true, x_pred, y_obs, y_pred, bars))


def _point_data(problem, x_true, x_pred, y_obs, y_pred, bars) -> dict:
    """The arrays :func:`write_fields` writes, at the mesh vertices, by name (``x_pred_0``, …), checked."""
    disc = _problem(problem).disc
    x_pred, _ = batch(x_pred, disc.N, "x_pred")
    fields = {"x_pred": x_pred}
    if x_true is not None:
        x_true, _ = batch(x_true, disc.N, "x_true")
        if x_true.shape != x_pred.shape:
            raise ValueError(f"x_true has shape {x_true.shape} but x_pred has {x_pred.shape}")
        fields = {"x_true": x_true, "x_pred": x_pred, "x_error": x_pred - x_true}
    if bars is not None:
        if not (isinstance(bars, Mapping) and all(k in bars for k in ("std", "lo", "hi"))):
            raise TypeError(f"bars={shown(bars)} is not allowed; expected a dict with 'std', 'lo' and 'hi' "
                            "(pdeinv.posterior.predictive's result)")
        b = {k: batch(bars[k], disc.N, f"bars[{k!r}]")[0] for k in ("std", "lo", "hi")}
        wrong = [k for k, v in b.items() if v.shape != x_pred.shape]
        if wrong:
            raise ValueError(f"bars[{wrong[0]!r}] has shape {b[wrong[0]].shape} but x_pred has "
                             f"{x_pred.shape}")
        fields.update({f"x_{k}": v for k, v in b.items()})
        if x_true is not None:
            fields["x_outside"] = (x_true > b["hi"]).astype(float) - (x_true < b["lo"])
    for name, y in (("y_obs", y_obs), ("y_pred", y_pred)):
        if y is not None and observes_field(problem.operator):
            fields[name] = batch(y, disc.N, name)[0]
    return {f"{name}_{k}": v for name, X in fields.items() for k, v in enumerate(vertex_values(disc, X))}


def _write(path: Path, problem, data: dict) -> Path:
    import meshio

    mesh = problem.disc.basis.mesh
    if path.suffix.lower() == ".xdmf":
        with meshio.xdmf.TimeSeriesWriter(os.fspath(path), data_format="XML") as w:
            w.write_points_cells(points_3d(mesh), _cells(mesh))
            w.write_data(0.0, point_data=data)
    else:
        meshio.write(os.fspath(path), meshio.Mesh(points_3d(mesh), _cells(mesh), point_data=data))
    return path


def write_sensors(path, points) -> Path:
    """Sensor coordinates ``(n, dim)`` as vertex cells (ParaView: render as points)."""
    import meshio

    P = np.atleast_2d(np.asarray(points, dtype=float))
    P = np.c_[P, np.zeros((P.shape[0], 3 - P.shape[1]))]
    meshio.write(os.fspath(path), meshio.Mesh(P, [("vertex", np.arange(len(P))[:, None])]))
    return Path(path)


def _read_mesh(path: str) -> tuple:
    """``(points, cells, point_data)`` of a ``.vtu`` or ``.xdmf`` file (meshio)."""
    import meshio

    if path.endswith(".xdmf"):
        with meshio.xdmf.TimeSeriesReader(path) as r:
            points, cells = r.read_points_cells()
            _, data, _ = r.read_data(0)
        return points, cells, data
    m = meshio.read(path)
    return m.points, m.cells, m.point_data


def read_fields(path) -> tuple:
    """``(mesh_points (nv, 3), cells, {kind: (B, nv)})`` from a file written by :func:`write_fields`; a
    ``ValueError`` naming the file when it cannot be read."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"fields file {path!r} does not exist; "
                                "run `pdeinv train ... --out DIR` first")
    import contextlib
    import io

    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            points, cells, data = _read_mesh(path)
    except (Exception, SystemExit) as err:  # noqa: BLE001  meshio on a damaged file (it may sys.exit)
        text = said.getvalue().strip() if isinstance(err, SystemExit) else f"{type(err).__name__}: {err}"
        why = (text.splitlines() or ["meshio stopped"])[0][:160]
        raise ValueError(f"fields file {path!r} cannot be read ({why}); rerun `pdeinv train` to write it "
                         "again") from None
    out = {}
    for kind in KINDS:
        keys = [k for k in data if k.rsplit("_", 1)[0] == kind]
        keys.sort(key=lambda k: int(k.rsplit("_", 1)[1]))
        if keys:
            out[kind] = np.stack([np.asarray(data[k]) for k in keys])
    if "x_true" not in out:
        raise ValueError(f"fields file {path!r} holds no x_true_<k> arrays; expected a file written by "
                         "pdeinv.io.export.write_fields")
    cells = cells[0].data if hasattr(cells[0], "data") else cells[0][1]
    return points, cells, out


def predict(model, y, problem=None) -> np.ndarray:
    """``f(y)`` as float64 numpy ``(B, N)``, evaluated without gradients in the model's dtype.

    ``model`` a ``torch.nn.Module`` (``result.model`` of :func:`pdeinv.train`, or :func:`pdeinv.load_run`'s);
    ``y`` observations ``(B, m)`` or ``(m,)`` (a numpy array or tensor; finite). With ``problem``, ``m``
    is checked against ``problem.operator.n_out``; without, a width the network cannot take is a
    ``ValueError`` naming ``y``'s shape.
    """
    import torch

    from ..problem.trained import trained_for
    from ..problem.units import input_dtype
    from ..training import arguments as _arguments

    model = _arguments.model(model, optional=False)
    if isinstance(y, torch.Tensor):
        y = y.detach().cpu().numpy()
    if isinstance(y, torch.nn.Module) or _arguments._is_result(y):
        raise TypeError("y is a network; the arguments are predict(model, y): swapped?")
    if problem is not None:
        trained_for(model, _problem(problem))
    width = None if problem is None else problem.operator.n_out
    Y = np.asarray(y)
    if width is None and Y.ndim in (1, 2) and Y.size:
        width = Y.shape[-1]  # the shape is checked by the network below
    if width is None:
        raise ValueError(f"y has shape {Y.shape}; expected observations (B, m) or (m,)")
    Y, single = batch(Y, width, "y")
    param = next(iter(model.parameters()), None)
    dtype = input_dtype(model)
    with torch.no_grad():
        try:
            out = model(torch.as_tensor(Y, dtype=dtype, device=getattr(param, "device", None)))
        except RuntimeError as err:  # a shape the network's layers refuse
            first = (str(err).strip().splitlines() or [""])[0][:120]
            raise ValueError(f"y has shape {np.shape(y)}; the network does not take {width} observations per "
                             f"row ({first}); expected the width it was trained on (the run's "
                             "problem.operator.n_out)") from None
    out = out.double().cpu().numpy()
    return out[0] if single else out


def export_run(out, problem, model, x, y, samples: int = 3, png: bool = True, posterior=None) -> dict:
    """A run's pictures and ParaView files for the first ``samples`` of ``(x, y)``; with the run's
    ``posterior``, its std and 90 % intervals too (:func:`write_fields`' ``bars``).

    Writes ``out/fields.vtu`` (see :func:`write_fields`), ``out/sensors.vtu`` when
    the problem has ``settings['sensor_points']``, and ``out/fields.png`` (only with true
    fields: ``x=None`` writes the predictions alone; 3-D fields as mid-plane slices,
    :func:`pdeinv.io.plots.mid_slice`). Returns
    ``{name: path}`` of what was written.
    """
    out = Path(out)
    x = None if x is None else np.asarray(x)[:samples]
    y = np.asarray(y)[:samples]
    xhat = predict(model, y)
    yhat = problem.operator.forward(xhat)
    bars = None
    if posterior is not None:
        from ..posterior import predictive

        bars = predictive(model, posterior, y)
    written = {"fields": fields_file(out / "fields.vtu", problem, x, xhat, y, yhat, bars)}
    points = problem.settings.get("sensor_points") if isinstance(problem.settings, dict) else None
    if points is not None:
        written["sensors"] = write_sensors(out / "sensors.vtu", points)
    if png and x is not None:
        written["png"] = save_fields_png(out / "fields.png", *read_fields(written["fields"]),
                                         title=f"{problem.name}: test samples")
    return written
