"""``pdeinv stress``: sweeps that try to break the numerics; every case's outcome in DIR/stress.json."""

from __future__ import annotations

from . import add_set_argument, parse_sets, prepare_out

ORDER = 3


def cmd_stress(args) -> int:
    import json
    from pathlib import Path

    from pdeinv.bench import cases, stress
    from pdeinv.bench.run import jsonable
    from pdeinv.bench.timing import machine
    from pdeinv.checkpoint import atomic_write
    from pdeinv.runlock import RunLock

    todo = cases.cases(args.problem, parse_sets(args.set), quick=args.quick)
    out = Path(args.out)
    prepare_out(out)
    with RunLock(out):  # one run per --out: a second one is refused
        rows = stress.run(todo, log=print)
        summary = stress.counts(rows)
        text = json.dumps(jsonable({"problem": args.problem, "quick": args.quick, "machine": machine(),
                                    "counts": summary, "cases": rows}), indent=2, default=str).encode()
        atomic_write(out / "stress.json", lambda fh: fh.write(text))  # a kill never leaves half a file
    print(" ".join(f"{k} {n}" for k, n in summary.items()) + f" -> {out / 'stress.json'}")
    return 0


def add_parser(sub) -> None:
    s = sub.add_parser("stress", help="numerical stress sweeps; write DIR/stress.json")
    s.add_argument("problem")
    s.add_argument("--out", required=True, metavar="DIR")
    s.add_argument("--quick", action="store_true", help="fewer values per sweep, shorter training")
    add_set_argument(s)
    s.set_defaults(func=cmd_stress)
