"""SIGTERM (and SIGHUP, where nothing ignores it) handled as Ctrl-C is: raised where the program is, as
:class:`Terminated` (a ``KeyboardInterrupt``), so every ``finally`` and ``except BaseException`` runs —
an atomic write removes its temporary (:func:`pdeinv.util.files.atomic_write`), the run lock is released,
``pdeinv train`` names its last checkpoint — and the command exits with 143 (128 + SIGTERM; Ctrl-C: 130).
Both are held back while a module is being imported (an interrupted C-extension import broke every later
import of numpy and torch) and while a file is being written (:mod:`pdeinv.util.critical`: an interrupt
inside ``torch.save``'s C++ writer came out as ``RuntimeError: [enforce fail at inline_container.cc]``,
exit 1), and raised as soon as the import or the write is done.

Python's default for SIGTERM is to die on the spot: no cleanup, a stale ``.<name>.<random>.tmp`` left
beside the file being written, and nothing said. ``kill``, ``timeout``, a batch scheduler's
pre-emption and ``docker stop`` all send SIGTERM.
"""

from __future__ import annotations

import contextlib
import signal
import threading

from ..util import critical

#: exit codes of a command stopped by Ctrl-C (SIGINT) and by SIGTERM: 128 + the signal's number
INTERRUPTED, TERMINATED = 128 + signal.SIGINT, 128 + signal.SIGTERM


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread wherever it was."""


class HungUp(Terminated):
    """SIGHUP (the terminal that started the command closed), handled as SIGTERM; exit 129."""


#: the interruption held back while a module was being imported (None: none)
_pending: type[BaseException] | None = None
#: how soon a held-back interruption is tried again (seconds)
RETRY_S = 0.02


def _held_back(frame) -> bool:
    """Whether ``frame`` runs inside an import (an importlib frame on its stack) or a finalizer (a
    ``__del__``: Python prints an exception raised there as "Exception ignored in" and goes on, so the
    signal would be lost: numpy's ``NpzFile.__del__`` once swallowed a SIGTERM this way) — unless a user's
    problem module's own code comes first (:data:`~pdeinv.util.critical.USER_MODULE_PREFIX`: a loop at its
    top level was stoppable only by SIGKILL); an import *it* makes is held back as any other."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib") or frame.f_code.co_name == "__del__":
            return True
        name = frame.f_globals.get("__name__")
        if isinstance(name, str) and name.startswith(critical.USER_MODULE_PREFIX):
            return False
        frame = frame.f_back
    return False


def _deliver(kind: type[BaseException], frame) -> None:
    """Raise ``kind`` here, unless a critical section runs (:func:`pdeinv.util.critical.inside`: a file
    being written; then it is raised as the section ends) or a module is being imported: an exception
    inside a C extension's import leaves it half-initialised, and the next import of numpy or torch then
    fails or crashes the interpreter (measured: Ctrl-C 0.5 s into ``pdeinv train`` gave "cannot load module
    more than once per process", at 0.6 s SIGSEGV); or a finalizer runs (:func:`_held_back`). Then it is
    held back and tried again every :data:`RETRY_S` seconds (SIGALRM) until the import is done."""
    global _pending
    if critical.inside():
        critical.hold(lambda: _deliver(kind, None))
        return
    if _held_back(frame) and hasattr(signal, "setitimer"):
        _pending = kind
        signal.setitimer(signal.ITIMER_REAL, RETRY_S)
        return
    _pending = None
    err = kind()
    err.from_signal = True  # a user's module raising KeyboardInterrupt itself is not (from_signal)
    raise err


def _on_interrupt(signum, frame):
    _deliver(KeyboardInterrupt, frame)


def _on_terminate(signum, frame):
    _deliver(Terminated, frame)


def _on_hangup(signum, frame):
    _deliver(HungUp, frame)


def _on_retry(signum, frame):
    if _pending is not None:
        _deliver(_pending, frame)


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within the block, SIGTERM raises :class:`Terminated` and Ctrl-C ``KeyboardInterrupt``, each held
    back while a module is being imported (:func:`_deliver`); the previous handlers are put back after
    (the test suite calls the CLI in its own process). A no-op outside the main thread."""
    global _pending
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handlers = {signal.SIGTERM: _on_terminate, signal.SIGINT: _on_interrupt}
    if hasattr(signal, "SIGALRM"):
        handlers[signal.SIGALRM] = _on_retry
    if hasattr(signal, "SIGHUP") and signal.getsignal(signal.SIGHUP) is signal.SIG_DFL:  # not under nohup
        handlers[signal.SIGHUP] = _on_hangup
    previous = {sig: signal.signal(sig, handler) for sig, handler in handlers.items()}
    try:
        yield
    finally:
        if hasattr(signal, "setitimer"):
            signal.setitimer(signal.ITIMER_REAL, 0)
        _pending = None
        critical.hold(None)
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def from_signal(err: BaseException) -> bool:
    """Whether ``err`` is a Ctrl-C or SIGTERM of the user's (raised by these handlers, or by Python's own
    where they are not installed), not a ``KeyboardInterrupt`` a module raised by itself."""
    ours = signal.getsignal(signal.SIGINT) is _on_interrupt
    return getattr(err, "from_signal", False) or not ours


def exit_code(err: BaseException) -> int:
    """129 for SIGHUP, 143 for SIGTERM, 130 for Ctrl-C."""
    if isinstance(err, HungUp):
        return 128 + signal.SIGHUP
    return TERMINATED if isinstance(err, Terminated) else INTERRUPTED


def what(err: BaseException) -> str:
    """``"hung up (SIGHUP)"``, ``"terminated (SIGTERM)"`` or ``"interrupted"``, for the one line a stopped
    command prints."""
    if isinstance(err, HungUp):
        return "hung up (SIGHUP)"
    return "terminated (SIGTERM)" if isinstance(err, Terminated) else "interrupted"
