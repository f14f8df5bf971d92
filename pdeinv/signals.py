"""SIGTERM handled as Ctrl-C is: raised where the program is, as :class:`Terminated` (a
``KeyboardInterrupt``), so every ``finally`` and ``except BaseException`` runs — an atomic write removes
its temporary (:func:`pdeinv.files.atomic_write`), the run lock is released, ``pdeinv train`` names its
last checkpoint — and the command exits with 143 (128 + SIGTERM; Ctrl-C: 130).

Python's default for SIGTERM is to die on the spot: no cleanup, a stale ``.<name>.<random>.tmp`` left
beside the file being written, and nothing said. ``kill``, ``timeout``, a batch scheduler's
pre-emption and ``docker stop`` all send SIGTERM.
"""

from __future__ import annotations

import contextlib
import signal
import threading

#: exit codes of a command stopped by Ctrl-C (SIGINT) and by SIGTERM: 128 + the signal's number
INTERRUPTED, TERMINATED = 128 + signal.SIGINT, 128 + signal.SIGTERM


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread wherever it was."""


def _raise(signum, frame):
    raise Terminated()


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within the block, SIGTERM raises :class:`Terminated`; the previous handler is put back after
    (the test suite calls the CLI in its own process). A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def exit_code(err: BaseException) -> int:
    """143 for SIGTERM, 130 for Ctrl-C."""
    return TERMINATED if isinstance(err, Terminated) else INTERRUPTED


def what(err: BaseException) -> str:
    """``"terminated (SIGTERM)"`` or ``"interrupted"``, for the one line a stopped command prints."""
    return "terminated (SIGTERM)" if isinstance(err, Terminated) else "interrupted"
