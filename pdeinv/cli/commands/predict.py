"""``pdeinv predict RUN_DIR --data obs.npz --out pred.npz``: apply a trained network to new observations.

Reads ``y`` ``(B, m)`` (and ``x`` ``(B, N)`` if present, to report the error) from
``--data`` (:func:`pdeinv.training.data.read_npz`), rebuilds the run's problem and network
(:func:`pdeinv.io.runs.load_run`) and writes ``x`` ``(B, N)`` to ``--out`` atomically;
``--vtu FILE`` also writes every prediction (and true field and error, when ``x`` is
given) at the mesh vertices for ParaView (:func:`pdeinv.io.export.write_fields`). The observations
are checked against the run's physics first (:func:`pdeinv.training.data.against`): refused (exit 2) when
half of them or more is unexplained (another problem's data of the same shapes), a warning when
they are off by more than the run's noise level explains.
"""

from __future__ import annotations

from pathlib import Path

from pdeinv.util.outpaths import output_file

from . import UsageError, set_threads

ORDER = 2


def cmd_predict(args) -> int:
    import io
    import warnings

    import numpy as np

    from pdeinv.io.export import predict, write_fields
    from pdeinv.io.runs import load_run
    from pdeinv.training.data import FOREIGN, against, explained, read_meta, read_npz
    from pdeinv.util.files import atomic_write

    run = Path(args.run)
    run_files = [("the run's model", run / "model.pt"), ("the run's record", run / "run.json")]
    # the one output-path policy (pdeinv.util.outpaths): resolved, never an input, a run's file or (without
    # --overwrite) any existing file
    out = output_file(args.out, "--out", [("--data", args.data), *run_files], suffixes=(".npz",),
                      overwrite=args.overwrite)
    vtu = None if args.vtu is None else output_file(
        args.vtu, "--vtu", [("--data", args.data), *run_files, ("--out", args.out)],
        suffixes=(".vtu", ".xdmf"), overwrite=args.overwrite)
    set_threads(args.threads)
    problem, model = load_run(args.run)
    y, x = read_npz(args.data, problem.operator.n_out, problem.N)
    read_meta(args.data, problem.points)  # the file's points, if any, are the run's problem's
    what, figure = against(problem, y, x, args.data)  # checked against the run's physics
    if not figure <= FOREIGN:
        raise UsageError(f"--data {args.data!r} is not of this run's physics: its {what} is {figure:.3g} "
                         f"(run {problem.name}, trained at noise {problem.noise:g}); observations made by "
                         "another problem of the same shapes? predict with that problem's run")
    if not explained(figure, problem.noise):
        warnings.warn(f"--data {args.data!r}: its {what} is {figure:.3g}, above what the run's noise level "
                      f"{problem.noise:g} explains: the predictions are outside what it was trained for",
                      RuntimeWarning, stacklevel=2)
    xhat = predict(model, y)
    buffer = io.BytesIO()
    np.savez(buffer, x=xhat)
    atomic_write(out, lambda fh: fh.write(buffer.getvalue()))
    if vtu is not None:
        write_fields(vtu, problem, x, xhat, y, problem.operator.forward(xhat))
    error = "" if x is None else f", x_err {float(np.mean(problem.relative_error(xhat, x))):.3g}"
    print(f"{problem.name}: {len(xhat)} predictions{error} -> {args.out}"
          + (f", {args.vtu}" if args.vtu else ""))
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("predict", help="apply a trained network (a train --out DIR) to observations (.npz)")
    p.add_argument("run", metavar="RUN_DIR", help="the --out DIR of a finished `pdeinv train`")
    p.add_argument("--data", required=True, metavar="FILE.npz",
                   help="observations: an .npz with y (B, m); x (B, N) if present reports the error")
    p.add_argument("--out", required=True, metavar="FILE.npz", help="where to write x (B, N)")
    p.add_argument("--vtu", default=None, metavar="FILE.vtu",
                   help="also write the predicted fields (and true ones and errors, with x) for ParaView")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --out or --vtu file (never a run's own files nor an input)")
    p.add_argument("--threads", type=int, default=1,
                   help="threads of torch and of numpy/scipy's BLAS (default 1)")
    p.set_defaults(func=cmd_predict)
