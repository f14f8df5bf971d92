"""Critical sections: code a signal must not cut short, such as a file being written
(:func:`pdeinv.util.files.atomic_write`).

A signal handler that raises (:mod:`pdeinv.cli.signals`: SIGTERM and Ctrl-C as exceptions) asks
:func:`inside` and, while a section runs, hands its action to :func:`hold` instead: it runs as the
outermost section ends, so the exception comes out right after the write. An exception raised inside a
write that torch's C++ serializer makes (``torch.save`` of a checkpoint) came out as ``RuntimeError:
[enforce fail at inline_container.cc:672]`` and exit 1 instead of the interrupt (1 in 17 SIGTERMs of a
checkpointing run). Standard library only: the signal handlers read it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable

#: the module names a user's problem module is imported under (:func:`pdeinv.problem.definition.
#: import_module`): its own code runs with an import on the stack, but an interrupt there is safe (a slow
#: loop or read of the user's, not a C extension's initialisation), so signals are not held back for it
USER_MODULE_PREFIX = "pdeinv_problem_"

_depth = 0
_held: Callable[[], None] | None = None


@contextlib.contextmanager
def section():
    """Within the block :func:`inside` is true (sections nest); as the outermost one ends, the action
    :func:`hold` was given runs (and may raise)."""
    global _depth, _held
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0 and _held is not None:
            action, _held = _held, None
            action()


def inside() -> bool:
    """Whether a :func:`section` is running."""
    return _depth > 0


def hold(action: Callable[[], None] | None) -> None:
    """Run ``action`` when the outermost running section ends (``None``: nothing)."""
    global _held
    _held = action
