"""``pdeinv predict RUN_DIR --data obs.npz --out pred.npz``: apply a trained network to new observations.

Reads ``y`` ``(B, m)`` (and ``x`` ``(B, N)`` if present, to report the error) from
``--data`` (:func:`pdeinv.training.data.read_npz`), rebuilds the run's problem and network
(:func:`pdeinv.io.runs.load_run`) and writes ``x`` ``(B, N)`` to ``--out`` atomically;
``--vtu FILE`` also writes every prediction (and true field and error, when ``x`` is
given) at the mesh vertices for ParaView (:func:`pdeinv.io.export.write_fields`). When the run has a
calibrated posterior (``posterior.npz``, :mod:`pdeinv.posterior.stage`), ``--out`` also holds
``std``, ``lo`` and ``hi`` (the central interval at ``--level``, 0.9 by default) and, with
``--samples K``, ``samples`` ``(B, K, N)`` (:func:`pdeinv.posterior.predictive`). The observations
are checked against the run's physics first (:func:`pdeinv.training.data.against`): refused (exit 3, one
line; ``--accept-bad`` predicts anyway) beyond the limit ``pdeinv classical`` and ``train`` apply
(:func:`pdeinv.training.data.beyond_noise`) or when they show no signal (pure noise, all zeros:
:func:`pdeinv.training.data.no_signal`, the check of ``train`` and ``classical``), a warning when they are
off by more than the run's noise level explains.
"""

from __future__ import annotations

from pathlib import Path

from pdeinv.util.outpaths import output_file

from . import PLAIN_FLOAT, PLAIN_INT, BadData, UsageError, set_threads

ORDER = 2


def cmd_predict(args) -> int:
    import io

    import numpy as np

    from pdeinv.io.export import fields_file, predict
    from pdeinv.io.runs import load_posterior, load_run
    from pdeinv.posterior import predictive
    from pdeinv.training.data import read_meta, read_npz
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
    level = _level(args)
    set_threads(args.threads)
    problem, model = load_run(args.run)
    posterior = load_posterior(args.run, problem)
    if posterior is None and (args.level is not None or args.samples is not None):
        raise UsageError(f"run {args.run!r} has no calibrated posterior (no posterior.npz: trained on a file "
                         "without x, or before calibration existed), so --level and --samples have nothing "
                         "to give; retrain it with `pdeinv train`")
    if posterior is not None and (args.samples or 0) > len(posterior.residuals):
        raise UsageError(f"--samples {args.samples} is not allowed: run {args.run!r} keeps "
                         f"{len(posterior.residuals)} residuals and each sample is one of them; expected at "
                         f"most {len(posterior.residuals)}")
    if args.seed < 0:
        raise UsageError(f"--seed {args.seed} is not allowed; expected an integer >= 0")
    y, x = read_npz(args.data, problem.operator.n_out, problem.N)
    declared = read_meta(args.data, problem.points).get("noise")  # its points, if any, are the run's
    _check_data(args, problem, y, x, model, declared)
    _say_if_failed(run)  # after the checks: a refused input is one line
    xhat = predict(model, y)
    if not np.isfinite(xhat).all():  # --accept-bad keeps odd data, never NaN/Inf answers
        bad = int((~np.isfinite(xhat)).sum())
        raise BadData(f"--data {args.data!r}: the run's predictions of it are not finite ({bad} of "
                      f"{xhat.size} values NaN or Inf): the observations lie far outside what the run was "
                      "trained on (in other units?); nothing was written")
    arrays = {"x": xhat} if posterior is None else \
        predictive(model, posterior, y, level, args.samples or 0, seed=args.seed)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    atomic_write(out, lambda fh: fh.write(buffer.getvalue()))
    if vtu is not None:
        fields_file(vtu, problem, x, xhat, y, problem.operator.forward(xhat),
                     None if posterior is None else arrays)
    error = "" if x is None else f", x_err {float(np.mean(problem.relative_error(xhat, x))):.3g}"
    if posterior is not None:
        error += f", {100 * level:.4g} % intervals" + ("" if x is None else (
            f" cover {float(np.mean((arrays['lo'] <= x) & (x <= arrays['hi']))):.3g} of the true values"))
    print(f"{problem.name}: {len(xhat)} predictions{error} -> {args.out}"
          + (f", {args.vtu}" if args.vtu else ""))
    return 0


def _say_if_failed(run: Path) -> None:
    """A warning when the run's own verdict failed it (``metrics.json``'s ``failed``, kept by
    ``--accept-bad`` or written before its exit 3): its predictions are no better than that verdict."""
    import json
    import logging

    try:
        failed = json.loads((run / "metrics.json").read_text()).get("failed")
    except (OSError, ValueError, AttributeError):
        return
    if failed:
        logging.getLogger("pdeinv").warning(f"pdeinv predict: warning: run {str(run)!r} failed its own check "
                                            f"({str(failed)[:160]}); its predictions are no better")


def _check_data(args, problem, y, x, model, declared=None) -> None:
    """The observations against the run's physics (module docstring): :class:`BadData` beyond the limit,
    far below the noise level the file ``declared`` (with x), or without signal (pure noise, all zeros:
    the checks of ``train`` and ``classical``), unless ``--accept-bad``; a warning then, and where they are
    off by more than the run's noise level explains."""
    import logging

    from pdeinv.training.data import (
        against,
        below_noise,
        beyond_noise,
        explained,
        no_signal,
        npz_rounding_level,
        read_noise,
    )

    _check_units(args, y, model)
    what, figure = against(problem, y, x, args.data)
    beyond = beyond_noise(what, figure, problem.noise, y, x)
    low = below_noise(figure, declared) if declared and x is not None else None
    why = no_signal(read_noise(y, problem.operator), len(y)) if beyond is None else \
        f"is not of this run's physics (run {problem.name}): {beyond}"
    why = f"has a wrong noise level: {low}" if low is not None and why is None else why
    if why is None and x is None:  # y alone: the verdict train gives such a file (pdeinv.training.verdict)
        why = _no_field(args, problem, y, model)
    rounding = npz_rounding_level(args.data)
    if why is not None and rounding > problem.noise:  # the file's storage may be the cause (train names it)
        why += (f" (or its storage: y is stored in lower precision than float64, whose rounding is noise of "
                f"relative level {rounding:.2g}, above the run's noise level {problem.noise:g}: save it in "
                "float64)")
    if why is not None and not args.accept_bad:
        raise BadData(f"--data {args.data!r} {why}; --accept-bad predicts anyway")
    if why is not None or not explained(figure, problem.noise):
        logging.getLogger("pdeinv").warning(
            f"pdeinv predict: warning: --data {args.data!r} "
            + (why if why is not None else f"is off: its {what} is {figure:.3g}, above what the run's noise "
               f"level {problem.noise:g} explains") + "; the predictions are outside what it was trained for")


def _no_field(args, problem, y, model) -> str | None:
    """Why observations without ``x`` are no field of the run's prior: the predictions of their first
    :data:`AMPLITUDE_ROWS` rows are :data:`~pdeinv.training.verdict.AMPLITUDE` times the prior's amplitude per
    unit of the observations' or more (:func:`~pdeinv.training.verdict.amplitude`, the test of
    ``pdeinv train --data`` on y alone: wave_1d data fed to a heat_1d run), else None."""
    import torch

    from pdeinv.problem.units import input_dtype
    from pdeinv.training.verdict import AMPLITUDE, amplitude

    if problem.sampler is None:  # no prior to compare with
        return None
    rows = y[:AMPLITUDE_ROWS]
    tensor = torch.as_tensor(rows, dtype=input_dtype(model))
    ratio = amplitude(problem, model, (None, rows, tensor), args.seed)
    if ratio < AMPLITUDE:
        return None
    return (f"is no field of this run's prior: its predictions are {ratio:.3g}× the prior's rms amplitude, "
            f"per unit of the observations' (a file passes below {AMPLITUDE:g}×): data from another physics "
            "or settings such as κ, T or the mesh?")


#: the rows of a y-only file the amplitude test of :func:`_no_field` looks at (and as many prior draws)
AMPLITUDE_ROWS = 128


def _check_units(args, y, model) -> None:
    """Observations whose magnitude, in the units the run was trained in (:mod:`pdeinv.problem.units`), lies
    outside what it trains on as it is (:data:`~pdeinv.problem.units.AS_IS`) are in other units: the network
    never saw such inputs (its output was NaN at 1e300 and 1e193 × off at 1e-200). :class:`BadData`, unless
    ``--accept-bad``."""
    import numpy as np

    from pdeinv.problem.units import AS_IS, unwrap

    units = unwrap(model)[1]
    top = float(np.max(np.abs(y))) / units if np.size(y) else 0.0
    if top != 0.0 and not AS_IS[0] <= top <= AS_IS[1] and not args.accept_bad:
        raise BadData(f"--data {args.data!r} holds values up to {top * units:.3g}: {top:.3g} times the "
                      f"units the run was trained in ({units:g}), outside {AS_IS[0]:g} to {AS_IS[1]:g}: "
                      "other units than the run's; rescale them to the training data's (or train a run on "
                      "data in these units); --accept-bad predicts anyway")


def _level(args) -> float:
    """``--level`` (0.9 when not given), after checking it and ``--samples``."""
    level = 0.9 if args.level is None else args.level
    if not 0 < level < 1:
        raise UsageError(f"--level {args.level:g} is not allowed; expected a number in (0, 1), e.g. 0.9 for "
                         "90 % intervals")
    if args.samples is not None and args.samples < 1:
        raise UsageError(f"--samples {args.samples} is not allowed; expected a count >= 1 (leave it out "
                         "for no samples)")
    return level


def add_parser(sub) -> None:
    p = sub.add_parser("predict", help="apply a trained network (a train --out DIR) to observations (.npz)")
    p.add_argument("run", metavar="RUN_DIR", help="the --out DIR of a finished `pdeinv train`")
    p.add_argument("--data", required=True, metavar="FILE.npz",
                   help="observations: an .npz with y (B, m); x (B, N) if present reports the error")
    p.add_argument("--out", required=True, metavar="FILE.npz",
                   help="where to write x (B, N), and std, lo, hi when the run is calibrated")
    p.add_argument("--vtu", default=None, metavar="FILE.vtu",
                   help="also write the predicted fields (and true ones and errors, with x) for ParaView")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --out or --vtu file (never a run's own files nor an input)")
    p.add_argument("--level", type=PLAIN_FLOAT, default=None, metavar="L",
                   help="central interval level in (0, 1) for lo and hi (default 0.9)")
    p.add_argument("--samples", type=PLAIN_INT, default=None, metavar="K",
                   help="also write K posterior samples per observation, samples (B, K, N)")
    p.add_argument("--seed", type=PLAIN_INT, default=0, help="seed of the samples (default 0)")
    p.add_argument("--accept-bad", action="store_true",
                   help="predict even on observations beyond what the run's noise explains (another physics "
                        "or settings: else exit code 3 and one line), with a warning")
    p.add_argument("--threads", type=PLAIN_INT, default=1,
                   help="threads of torch and of numpy/scipy's BLAS (default 1)")
    p.set_defaults(func=cmd_predict)
