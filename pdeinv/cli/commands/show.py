"""``pdeinv show DIR``: PNG pictures of true vs predicted fields from a training run's ``fields.vtu``."""

from __future__ import annotations

from pathlib import Path

from . import UsageError

ORDER = 2


def _samples(text: str | None):
    if text is None:
        return None
    try:
        return [int(k) for k in text.split(",")]
    except ValueError:
        raise UsageError(f"--samples {text!r} is not a comma-separated list of integers, e.g. 0,2") from None


#: what ``--png`` may be written as (matplotlib's raster and vector formats most used)
IMAGES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def cmd_show(args) -> int:
    """Read ``DIR/fields.vtu`` (or ``.xdmf``) and write ``DIR/fields.png`` (or ``--png``)."""
    import matplotlib

    matplotlib.use("Agg")
    from pdeinv.io.export import read_fields
    from pdeinv.io.plots import save_fields_png
    from pdeinv.util.outpaths import output_file, resolve

    run = Path(args.dir)
    if not run.is_dir():
        raise UsageError(f"{str(run)!r} is not a directory; expected the --out DIR of `pdeinv train`")
    found = [run / name for name in ("fields.vtu", "fields.xdmf") if (run / name).is_file()]
    if not found and (run / "run.json").is_file():  # a run that wrote no fields (--export-samples 0)
        raise UsageError(f"run {str(run)!r} wrote no fields.vtu (trained with --export-samples 0?): nothing "
                         "to draw; retrain with --export-samples K")
    if not found:
        raise UsageError(f"{str(run)!r} holds no fields.vtu or fields.xdmf; "
                         "expected the --out DIR of `pdeinv train`")
    # the one output-path policy (pdeinv.util.outpaths): never the fields file drawn, nor another of the
    # run's files (--png RUN/training.png once replaced the run's training curves)
    # (another run's fields.png is that run's: only this run's own is redrawn)
    target = args.png if args.png is not None else run / "fields.png"
    own = resolve(target, "--png").parent == run.resolve()
    png = output_file(target, "--png", [("the fields file drawn", found[0])],
                      owns=("fields.png",) if own else (), overwrite=args.overwrite, suffixes=IMAGES)
    try:
        points, cells, fields = read_fields(found[0])
    except ValueError as err:
        if "x_true" not in str(err) or not (run / "run.json").is_file():
            raise
        raise UsageError(f"run {str(run)!r} was trained on data without x: its {found[0].name} holds the "
                         "estimates, and show draws true against predicted; open it in ParaView") from None
    try:
        save_fields_png(png, points, cells, fields, samples=_samples(args.samples), title=run.name)
    except ValueError as err:  # the samples' range, in the flag's words
        if not str(err).startswith("samples="):
            raise
        raise UsageError(f"--samples {args.samples} is not allowed; {str(err).split('; ', 1)[1]}") from None
    print(f"wrote {args.png if args.png is not None else run / 'fields.png'}")
    return 0


def add_parser(sub) -> None:
    s = sub.add_parser("show", help="PNG of true vs predicted vs error fields of a training run")
    s.add_argument("dir", metavar="DIR", help="the --out directory of `pdeinv train`")
    s.add_argument("--samples", default=None, metavar="K,K", help="which test samples (default: all written)")
    s.add_argument("--png", default=None, metavar="FILE.png",
                   help="output file (default DIR/fields.png; its folder is created; never another of the "
                        "run's files)")
    s.add_argument("--overwrite", action="store_true",
                   help="replace an existing --png file (the run's own fields.png is redrawn without it)")
    s.set_defaults(func=cmd_show)
