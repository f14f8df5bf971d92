"""``pdeinv bench``: run time against error, cost ratios and skips; writes DIR/bench.json and PNGs."""

from __future__ import annotations

from . import (
    PLAIN_FLOAT,
    PLAIN_INT,
    UsageError,
    add_set_argument,
    build_problem,
    no_cache,
    out_path,
    prepare_out,
    run_parser,
)

ORDER = 2


def cmd_bench(args) -> int:

    from pdeinv.bench import bench, summary
    from pdeinv.util.runlock import RunLock

    if args.budget_s is not None and not args.budget_s > 0:
        raise UsageError(f"--budget-s {args.budget_s!r} is not allowed; expected seconds > 0")
    if args.threads < 1:
        raise UsageError(f"--threads {args.threads} is not allowed; expected an integer >= 1")
    no_cache(args)
    problem = build_problem("bench", args.problem, args.set)
    out = out_path(args.out)
    prepare_out(out, record="bench.json", replace=args.overwrite)  # never a run's or a user's folder
    with RunLock(out):  # one run per --out: a second one is refused
        res = bench(problem, out, quick=args.quick, budget_s=args.budget_s, seed=args.seed,
                    threads=args.threads)
    print(summary(res))
    print(f"-> {out / 'bench.json'}")
    return 0


def add_parser(sub) -> None:
    b = run_parser(sub, "bench", "benchmark run time against error; write DIR/bench.json and plots",
                   quick="tiny sizes, no sweeps, one repeat, 1 s per method (CI smoke test, "
                         "27 s on heat_2d)")
    b.add_argument("--budget-s", type=PLAIN_FLOAT, default=None, metavar="S",
                   help="training wall time per method (default 20, 1 with --quick)")
    b.add_argument("--seed", type=PLAIN_INT, default=0,
                   help="seed of the draws, batch orders and initial weights (0 to 2^32-1; default 0)")
    b.add_argument("--no-cache", action="store_true", help="no disk cache of factorizations")
    b.add_argument("--threads", type=PLAIN_INT, default=1,
                   help="threads of torch and of numpy/scipy's BLAS during the run (default 1: steadier "
                        "timings on a shared machine)")
    add_set_argument(b)
    b.set_defaults(func=cmd_bench)
