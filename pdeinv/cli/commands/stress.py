"""``pdeinv stress``: sweeps that try to break the numerics; every case's outcome in DIR/stress.json."""

from __future__ import annotations

from . import add_set_argument, no_cache, out_path, parse_sets, prepare_out, run_parser

ORDER = 3


def cmd_stress(args) -> int:
    import json

    from pdeinv.bench import cases, stress
    from pdeinv.bench.run import jsonable
    from pdeinv.bench.timing import machine
    from pdeinv.util.files import atomic_write
    from pdeinv.util.outpaths import record_format
    from pdeinv.util.runlock import RunLock

    no_cache(args)
    todo = cases.cases(args.problem, parse_sets(args.set), quick=args.quick)
    out = out_path(args.out)
    prepare_out(out, record="stress.json", replace=args.overwrite)  # never a run's or a user's folder
    with RunLock(out):  # one run per --out: a second one is refused
        rows = stress.run(todo, log=print)
        summary = stress.counts(rows)
        record = {"format": record_format("stress.json"), "problem": args.problem, "quick": args.quick,
                  "machine": machine(), "counts": summary, "cases": rows}
        text = json.dumps(jsonable(record), indent=2, default=str).encode()
        atomic_write(out / "stress.json", lambda fh: fh.write(text))  # a kill never leaves half a file
    print(" ".join(f"{k} {n}" for k, n in summary.items()) + f" -> {out / 'stress.json'}")
    return 0


def add_parser(sub) -> None:
    s = run_parser(sub, "stress", "numerical stress sweeps; write DIR/stress.json",
                   quick="fewer values per sweep, shorter training")
    s.add_argument("--no-cache", action="store_true", help="no disk cache of factorizations")
    add_set_argument(s)
    s.set_defaults(func=cmd_stress)
