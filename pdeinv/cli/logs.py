"""What the command line says on stderr besides errors, through :mod:`logging` (logger ``"pdeinv"``):

* ``INFO`` (the default): progress a user waits on, e.g. ``building heat_2d…`` / ``built … in 41 s``
  for a slow problem, and the heartbeat of a long run whose stderr is not a terminal;
* ``DEBUG`` (``--verbose``): what was chosen for the user, e.g. the method's hyper-parameters and the
  physics backend;
* ``--quiet``: warnings, errors and the result line only (no progress bar either).

Python users see nothing unless they configure logging (``logging.basicConfig(level="INFO")``): the
library adds no handler of its own outside :func:`cli_logging`.
"""

from __future__ import annotations

import contextlib
import logging
import sys

LOGGER = logging.getLogger("pdeinv")


#: the library's progress lines (the trainer's stages) carry no command name: the handler says whose they are
PROGRESS = "pdeinv.progress"


class _Stderr(logging.Handler):
    """Writes each message to the *current* ``sys.stderr`` (a test's capture included), one line; a
    :data:`PROGRESS` line after the running command's name (``pdeinv bench: …`` where bench trains)."""

    def __init__(self, command: str | None = None):
        super().__init__()
        self.command = command

    def emit(self, record: logging.LogRecord) -> None:
        text = self.format(record)
        if record.name == PROGRESS:
            text = f"pdeinv {self.command or 'train'}: {text}"
        print(text, file=sys.stderr, flush=True)


def add_arguments(parser) -> None:
    """``-q/--quiet`` and ``-v/--verbose`` on a subcommand's parser."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("-q", "--quiet", action="store_true",
                       help="print only warnings, errors and the result (no progress)")
    group.add_argument("-v", "--verbose", action="store_true",
                       help="also print what was chosen for you (hyper-parameters, physics backend)")


def level(args) -> int:
    return logging.WARNING if getattr(args, "quiet", False) else (
        logging.DEBUG if getattr(args, "verbose", False) else logging.INFO)


@contextlib.contextmanager
def cli_logging(args):
    """The ``pdeinv`` logger at the level of ``--quiet`` / ``--verbose`` for one command, then as before."""
    handler, before, propagate = _Stderr(getattr(args, "command", None)), LOGGER.level, LOGGER.propagate
    LOGGER.addHandler(handler)
    LOGGER.setLevel(level(args))
    LOGGER.propagate = False
    try:
        yield LOGGER
    finally:
        LOGGER.removeHandler(handler)
        LOGGER.setLevel(before)
        LOGGER.propagate = propagate
