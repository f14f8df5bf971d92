"""One module per ``pdeinv`` subcommand; each exposes ``add_parser(subparsers)``.

``pdeinv.cli`` finds them by themselves (sorted by a module-level ``ORDER``).
``add_parser`` registers the subcommand's arguments and sets ``func`` (``args -> exit code``).
Modules import their heavy dependencies inside ``func`` so ``pdeinv --help`` stays fast.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

#: the exit code of results that cannot be right (``--accept-bad``: 0): a training run that failed its
#: verdict (:mod:`pdeinv.training.verdict`), classical solves that cannot be (``pdeinv classical``)
FAILED = 3


class UsageError(Exception):
    """A user mistake the CLI reports in one line (exit code 2)."""


class BadData(Exception):
    """Input whose results cannot be right (data of another physics, no signal), refused before any work:
    one line, exit code :data:`FAILED`; the command's ``--accept-bad`` lets it through."""


def ranged(action, low=None, above=None, below=None, high=None):
    """Declare the range of a numeric flag (``action``: what ``add_argument`` returned): at least ``low``,
    more than ``above``, less than ``below``, at most ``high``. :func:`pdeinv.cli.check_numbers` refuses a
    value outside it before any work, in one line naming the flag (not the setting it feeds)."""
    action.low, action.above, action.below, action.high = low, above, below, high
    return action


def declare_ranges(parser, ranges: dict) -> None:
    """:func:`ranged` for each flag of ``parser`` whose dest ``ranges`` names: ``{"steps": dict(low=1)}``."""
    for action in parser._actions:
        if action.dest in ranges:
            ranged(action, **ranges[action.dest])


def _plain(cast):
    """An argparse ``type``: ``cast(text)`` for plain ASCII numbers only; ``'２'``, ``'1_000'`` or ``' 2'``
    (which Python's ``int``/``float`` read as 2, 1000 and 2) are refused, as the settings refuse them."""
    def parse(text: str):
        if text != text.strip() or "_" in text or not text.isascii():
            raise argparse.ArgumentTypeError(f"{text!r} is not a plain number; expected ASCII digits such as "
                                             "16, 0.01 or 1e-3")
        return cast(text)

    parse.__name__ = cast.__name__  # argparse's "invalid int value: 'x'" for the rest
    parse.cast = cast  # what check_numbers checks the value as
    return parse


#: the numeric flags' argparse types (:func:`_plain`)
PLAIN_INT, PLAIN_FLOAT = _plain(int), _plain(float)


def parse_sets(pairs: list[str]) -> dict:
    """``["kappa=0.02", "mesh=f.msh"]`` -> ``{"kappa": "0.02", ...}`` (problems coerce types)."""
    out = {}
    for item in pairs or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UsageError(f"--set {item!r} is not KEY=VALUE")
        if value != value.strip() or key != key.strip():  # as the numeric flags: ' 2' is not a value
            raise UsageError(f"--set {item!r} has spaces around its key or value; expected KEY=VALUE without "
                             "them (e.g. --set kappa=0.02)")
        if key in out and out[key] != value.strip():  # which one the user meant is not ours to guess
            raise UsageError(f"--set {key}= is given twice, as {out[key]!r} and {value.strip()!r}; "
                             "expected one value per setting")
        out[key] = value.strip()
    return out


def add_set_argument(parser) -> None:
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="problem override, e.g. --set kappa=0.02 --set n=32")


def add_memory_argument(parser) -> None:
    parser.add_argument("--max-memory-gb", type=PLAIN_FLOAT, default=None, metavar="GB",
                        help="refuse a run whose estimated memory exceeds GB (default: 90%% of the "
                             "available memory; see pdeinv/util/memory.py)")


def build_problem(command: str, name: str, sets: list[str], after_s: float = 1.0, steps: int | None = None):
    """``pdeinv.load_problem(name, **parse_sets(sets))``, saying on stderr what it builds when that
    takes longer than ``after_s`` seconds (one line, then its time): a large mesh or a modal basis
    can take minutes. ``steps``: the training steps the run will take, for the backend's cost
    model (:func:`pdeinv.physics.backends.compiled.expecting`; ``None``: its default)."""
    import logging
    import threading
    import time

    import pdeinv
    from pdeinv.physics.backends.compiled import expecting

    if not str(name).strip():
        raise UsageError(f"PROBLEM {name!r} is empty; expected a problem name (pdeinv problems lists them) "
                         "or the path of a module file with make(**overrides)")
    overrides = parse_sets(sets)
    what = f"{name} ({', '.join(f'{k}={v}' for k, v in overrides.items())})" if overrides else name
    t0 = time.perf_counter()
    log = logging.getLogger("pdeinv")  # INFO: progress a user waits on (pdeinv.cli.logs, --quiet)
    timer = threading.Timer(after_s, lambda: log.info(f"pdeinv {command}: building {what}…"))
    timer.daemon = True
    timer.start()
    try:
        with expecting(steps=steps):
            problem = pdeinv.load_problem(name, **overrides)
    finally:
        timer.cancel()
    took = time.perf_counter() - t0
    if took > after_s:
        log.info(f"pdeinv {command}: built {problem.name} ({problem.N} unknowns) in {took:.1f} s")
    log.debug(f"pdeinv {command}: {problem!r}; backend {getattr(problem.operator, 'choice', 'n/a')}")
    return problem


def run_parser(sub, name: str, help: str, quick: str):
    """A subcommand parser with the arguments every sweep shares: PROBLEM, ``--out DIR``, ``--quick``."""
    p = sub.add_parser(name, help=help)
    p.add_argument("problem")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for the results (created with its parents)")
    p.add_argument("--quick", action="store_true", help=quick)
    p.add_argument("--overwrite", action="store_true",
                   help=f"replace the earlier results of pdeinv {name} in --out (refused without it)")
    add_memory_argument(p)
    return p


def out_path(text: str, flag: str = "--out") -> Path:
    """``--out`` as a path, refusing an empty one (it would silently mean the current folder)."""
    if not str(text).strip():
        raise UsageError(f"{flag} {text!r} is empty; expected a path")
    return Path(text)


def prepare_out(out, record: str | None = None, replace: bool = False) -> None:
    """Refuse an ``--out`` that is a file; create the folder and prove it writable before any work
    (:func:`pdeinv.util.outpaths.output_folder`, the policy of every output path). ``record``: the file a
    sweep writes there (``bench.json``): a folder holding anything else is refused, one holding the
    sweep's earlier results unless ``replace`` (``--overwrite``)."""
    from pdeinv.util.outpaths import output_folder

    output_folder(out, "--out", record=record, replace=replace)


#: the most ``--threads`` a command takes: beyond it the thread pools fail to start (measured: 100 000
#: threads, "can't start new thread" from a traceback), and no machine pdeinv runs on has more cores
THREADS_MAX = 1024


def set_threads(n: int) -> None:
    """``--threads``: torch's threads and every BLAS/OpenMP pool (:func:`pdeinv.util.threads.limit`), from 1
    to :data:`THREADS_MAX`."""
    if not 1 <= n <= THREADS_MAX:
        raise UsageError(f"--threads {n} is not allowed; expected an integer from 1 to {THREADS_MAX} "
                         f"(this machine has {os.cpu_count()} cores)")
    from pdeinv.util.threads import limit

    limit(n)


def no_cache(args) -> None:
    """``--no-cache``: ``PDEINV_NO_CACHE=1`` for this process (:mod:`pdeinv.util.cache` then recomputes)."""
    if getattr(args, "no_cache", False):
        os.environ["PDEINV_NO_CACHE"] = "1"
