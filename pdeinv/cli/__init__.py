"""Command line: ``pdeinv demo | train | ...``, one module per subcommand in :mod:`pdeinv.cli.commands`.

Errors a user can fix (bad settings, missing files, an ``--out`` folder another run
holds, a user's problem module that fails) end with exit code 2 and a one-line message on stderr, never a
traceback (``-v`` prints the traceback of what a user's module raised before that line); a
numerical failure on valid input (:mod:`pdeinv.errors`) or running out of memory ends
with exit code 1 and one line that says what to change; a training run that failed its
final check (:mod:`pdeinv.training.verdict`: worse than predicting zero) ends with exit code 3 and one
line after writing its files, and data that cannot be right (:class:`~pdeinv.cli.commands.BadData`:
another physics' observations, no signal) with exit code 3 and one line before any work, unless
``--accept-bad``; Ctrl-C ends with 130 and one line, SIGTERM the same way with 143
(:mod:`pdeinv.cli.signals`), and Ctrl-C before the command started (imports, parsing) with 130 and no
output. Any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import re
import sys

from ..errors import numerical_types
from ..training.arguments import SEED_MAX
from ..util.runlock import FolderLocked
from . import commands
from .commands import FAILED, BadData, UsageError, parse_sets

__all__ = ["UsageError", "build_parser", "main", "parse_sets"]


def command_modules() -> list:
    """Every module in :mod:`pdeinv.cli.commands` with an ``add_parser``, ordered by its ``ORDER``."""
    found = [importlib.import_module(f"{commands.__name__}.{m.name}")
             for m in pkgutil.iter_modules(commands.__path__)]
    found = [m for m in found if hasattr(m, "add_parser")]
    return sorted(found, key=lambda m: (getattr(m, "ORDER", 100), m.__name__))


class _Once(argparse._StoreAction):
    """argparse's ``store``, refusing a flag given twice with two values (argparse keeps the last one
    silently: ``--steps 2 --steps 3`` or two ``--out`` folders are a typo or a pasted command, not a
    choice); the same value twice is that value."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = self.__dict__.setdefault("_given", {})
        if option_string is not None and id(namespace) in given and given[id(namespace)] != values:
            parser.error(f"{option_string} is given twice, as {given[id(namespace)]!r} and {values!r}; "
                         "give it once")
        given[id(namespace)] = values
        super().__call__(parser, namespace, values, option_string)


class Parser(argparse.ArgumentParser):
    """argparse's parser, with its errors (an unknown flag, a value of the wrong type, a flag given twice:
    :class:`_Once`) in one line, as every other error of the CLI: argparse prints the whole usage block
    first (12 lines for ``train``)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.register("action", None, _Once)
        self.register("action", "store", _Once)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (`{self.prog} --help` lists the arguments)\n")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    p = Parser(prog="pdeinv", description="PDE inverse problems on finite elements.")
    p.add_argument("--version", action="version", version=f"pdeinv {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for module in command_modules():
        module.add_parser(sub)
    from .logs import add_arguments

    for command in sub.choices.values():  # -q/--quiet, -v/--verbose on every subcommand (pdeinv.cli.logs)
        add_arguments(command)
    p.commands = sub.choices  # each subcommand's parser: its own errors name its own --help
    return p


#: the largest value of an integer flag (``--steps``, ``--threads``, ``--prior-fit``, ...; ``--seed`` has
#: its own range): a count beyond int32 is a typo, and overflows C integers where it is used
INT_MAX = 2**31 - 1


def check_numbers(parser, args) -> None:
    """Every numeric flag of the command, checked once before any work: a float flag finite (``nan``,
    ``inf`` refused), an integer flag at most :data:`INT_MAX` in magnitude, and within the range the flag
    declares (:func:`pdeinv.cli.commands.ranged`: ``--steps`` >= 1, ``--lr`` > 0, ...); the one line names
    the flag. Ranges that depend on other values (``--batch-size`` against ``--n-train``) are checked where
    they are used."""
    import math

    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for action in subparsers.choices[args.command]._actions:
        value, cast = getattr(args, action.dest, None), _cast(action)
        if value is None or cast not in (int, float) or not action.option_strings \
                or action.dest == "seed":  # --seed: 0 to 2^32 - 1 (check_common)
            continue
        flag = max(action.option_strings, key=len)
        if cast is float and not math.isfinite(value):
            raise UsageError(f"{flag} {value} is not allowed; expected a finite number")
        if cast is int and abs(value) > INT_MAX:
            raise UsageError(f"{flag} {value} is out of range; expected an integer of at most {INT_MAX}")
        _in_range(action, flag, value)


def _cast(action):
    """The number type a flag's argparse ``type`` reads (``int`` for ``PLAIN_INT``)."""
    return getattr(action.type, "cast", action.type)


def _in_range(action, flag: str, value) -> None:
    """``value`` within the range ``action`` declares (:func:`pdeinv.cli.commands.ranged`), or one line."""
    low, above, below, high = (getattr(action, k, None) for k in ("low", "above", "below", "high"))
    if (low is None or value >= low) and (above is None or value > above) \
            and (below is None or value < below) and (high is None or value <= high):
        return
    kind = "an integer" if _cast(action) is int else "a number"
    parts = [f">= {low}" if low is not None else "", f"> {above}" if above is not None else "",
             f"< {below}" if below is not None else "", f"<= {high}" if high is not None else ""]
    allowed = " and ".join(p for p in parts if p)
    raise UsageError(f"{flag} {value:g} is not allowed; expected {kind} {allowed}")


def check_common(args) -> None:
    """Options several subcommands share, checked once before any work: ``--seed`` in
    ``0..2³²−1``, ``--max-memory-gb`` > 0 (set as :mod:`pdeinv.util.memory`'s budget), and
    ``$PDEINV_CACHE_MAX_GB`` where set (:func:`pdeinv.util.cache.max_bytes`, read only when the cache
    writes: a value that is no number went unnoticed on small scenes)."""
    seed = getattr(args, "seed", None)
    if seed is not None and not 0 <= seed <= SEED_MAX:
        raise UsageError(f"--seed {seed} is not allowed; expected an integer from 0 to {SEED_MAX}")
    if os.environ.get("PDEINV_CACHE_MAX_GB") is not None:
        from ..util.cache import max_bytes

        max_bytes()
    from ..util import memory

    memory.set_budget(getattr(args, "max_memory_gb", None))  # None: the default (each call anew)
    if os.environ.get("MPLBACKEND"):  # else read when the figures are drawn, after the work (a half run)
        try:  # matplotlib reads it as it is imported
            from matplotlib import rcsetup

            rcsetup.validate_backend(os.environ["MPLBACKEND"])
        except ValueError:
            raise UsageError(f"MPLBACKEND={os.environ['MPLBACKEND']!r} is not a backend of matplotlib's; "
                             "unset it, or set it to one such as 'Agg'") from None


class _Closed:
    """``sys.stdout`` where the shell closed it (``>&-``: Python sets it to ``None`` and every print is
    lost): a write fails as on a broken pipe, so the command says so and exits non-zero."""

    def write(self, text):
        import errno

        raise OSError(errno.EBADF, "standard output is closed")

    def flush(self):
        pass


def _streams() -> None:
    """Characters the terminal's encoding lacks (κ, –) as escapes, not a UnicodeEncodeError; a closed
    stdout as :class:`_Closed`."""
    if sys.stdout is None:
        sys.stdout = _Closed()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.reconfigure(errors="backslashreplace")
        except (AttributeError, ValueError, OSError):  # not a text file of io's (a test's capture)
            pass


def main(argv=None) -> int:
    _streams()
    try:
        from .signals import terminate_as_interrupt
    except KeyboardInterrupt:  # Ctrl-C before the handlers are in place: quietly, as after
        return 130

    import gc

    from .signals import exit_code

    with terminate_as_interrupt():  # SIGTERM unwinds as Ctrl-C does (pdeinv.cli.signals)
        try:
            code = _main(argv)
        except KeyboardInterrupt as err:  # during start-up (imports, parsing): quietly
            code = exit_code(err)
        try:
            # the frames of an interrupted command form cycles that hold its solvers: freed now, not left
            # alive at exit, where nanobind reports each (a sparse Cholesky's) as "leaked" in 8 lines
            gc.collect()
        except KeyboardInterrupt as err:  # a signal as the command ends: its work is done, quietly
            code = exit_code(err)
        return code


def _user_frame(err: BaseException):
    """The innermost frame of ``err``'s traceback in code that is neither pdeinv's nor an installed
    package's nor the standard library's (a user's problem module or sampler), or None."""
    import sysconfig
    import traceback
    from pathlib import Path

    ours = Path(__file__).resolve().parent.parent
    installed = {Path(p).resolve() for p in {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib",
                                                                              "purelib", "platlib")}}
    user = None
    for frame in traceback.extract_tb(err.__traceback__):
        here = Path(frame.filename)
        if frame.filename.startswith("<") or not here.is_absolute():
            continue
        here = here.resolve()
        if not here.is_relative_to(ours) and not any(here.is_relative_to(p) for p in installed):
            user = frame
    return user


def _unexpected(args, err: Exception) -> int:
    """An exception no clause names: one line and exit 2 when it was raised in a user's code (file and
    line), else one line naming it an internal error, exit 1; the traceback with ``-v``."""
    from ..problem.definition import first_line

    if getattr(args, "verbose", False):
        import traceback

        traceback.print_exception(err, file=sys.stderr)
    text = first_line(err)
    what = f"{type(err).__name__}: {text}" if text else type(err).__name__
    frame = _user_frame(err)
    if frame is not None:
        print(f"pdeinv {args.command}: error: {frame.filename}, line {frame.lineno}, in {frame.name}: {what} "
              "(-v shows the traceback)", file=sys.stderr)
        return 2
    print(f"pdeinv {args.command}: internal error: {what} (-v shows the traceback; please report it)",
          file=sys.stderr)
    return 1


def _thread_failed(args, hook_args) -> None:
    """``threading.excepthook`` of a command without ``-v``: an exception that ended a thread (a user's
    module may start one) in one line, with the user's file and line where it was raised there."""
    from ..problem.definition import first_line

    err = hook_args.exc_value
    if err is None or isinstance(err, SystemExit):
        return
    text = first_line(err)
    frame = _user_frame(err)
    where = "" if frame is None else f" at {frame.filename}, line {frame.lineno}, in {frame.name}"
    name = getattr(hook_args.thread, "name", "a thread")
    print(f"pdeinv {args.command}: warning: thread {name!r} ended{where}: {type(err).__name__}"
          + (f": {text}" if text else "") + " (-v shows the traceback)", file=sys.stderr)


#: a negative number with an exponent, or ``-inf``/``-nan``, which argparse takes for an option (it knows
#: ``-1`` and ``-0.5`` only)
_NEGATIVE_EXP = re.compile(r"-((\d+\.?\d*|\.\d+)e[-+]?\d+|inf|infinity|nan)", re.IGNORECASE)


def _joined(argv: list[str]) -> list[str]:
    """``--lr -1e-3`` (or ``-inf``) as ``--lr=-1e-3``, so the option's own check names the value."""
    out: list[str] = []
    for token in argv:
        if (out and _NEGATIVE_EXP.fullmatch(token) and out[-1].startswith("--") and "=" not in out[-1]
                and out[-1] != "--"):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def _main(argv=None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(_joined(sys.argv[1:] if argv is None else list(argv)))
    if extra:  # the subcommand's parser says it, so the message names `pdeinv train --help`
        parser.commands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    import threading
    import warnings

    from .logs import cli_logging

    hook = threading.excepthook
    if not getattr(args, "verbose", False):
        threading.excepthook = lambda t: _thread_failed(args, t)
    try:
        check_numbers(parser, args)
        check_common(args)
        with cli_logging(args), warnings.catch_warnings():
            # a warning in one line, as every message of the CLI (Python's adds its file and source line)
            warnings.showwarning = lambda message, *_, **__: print(
                f"pdeinv {args.command}: warning: {message}", file=sys.stderr)
            return args.func(args)
    except KeyboardInterrupt as err:  # first: the clauses below import numpy, which may be half-imported
        from .signals import exit_code, what  # `train` reports its checkpoint itself, 130 / 143

        print(f"pdeinv {args.command}: {what(err)}", file=sys.stderr)
        return exit_code(err)
    except BadData as err:
        print(f"pdeinv {args.command}: error: {err}", file=sys.stderr)
        return FAILED
    except numerical_types() as err:  # before ValueError: numpy's LinAlgError is one
        print(f"pdeinv {args.command}: numerical failure: {err}", file=sys.stderr)
        return 1
    except (UsageError, FolderLocked, ValueError, FileNotFoundError, NotImplementedError) as err:
        if getattr(args, "verbose", False) and err.__cause__ is not None:  # e.g. a user's problem module
            import traceback

            traceback.print_exception(err.__cause__, file=sys.stderr)
        print(f"pdeinv {args.command}: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # a folder that went away or became read-only after the checks, a full disk
        where = f" ({err.filename})" if getattr(err, "filename", None) else ""
        print(f"pdeinv {args.command}: error: cannot write: {err.strerror or err}{where}", file=sys.stderr)
        return 1
    except MemoryError as err:
        print(f"pdeinv {args.command}: out of memory: {err or 'no message'}; use a coarser mesh, a smaller "
              "batch or fewer samples", file=sys.stderr)
        return 1
    except Exception as err:  # noqa: BLE001  last: raised in a user's code (a problem module), or a bug
        return _unexpected(args, err)
    finally:
        threading.excepthook = hook
        # --threads bounded the BLAS pools for this command only; a command that never set them (or was
        # interrupted while torch was being imported) must not import torch here: a second import of a
        # half-imported torch crashes the interpreter (measured: SIGSEGV after Ctrl-C at 0.6 s)
        threads = sys.modules.get(f"{__package__.rpartition('.')[0]}.util.threads")
        if threads is not None:
            threads.restore()


if __name__ == "__main__":
    sys.exit(main())
