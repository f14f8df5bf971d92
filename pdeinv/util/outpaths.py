"""One policy for every path pdeinv writes to (``train --out``, ``predict --out/--vtu``, ``show --png``,
``classical --out``, :func:`pdeinv.save_run`), checked before any work:

* an empty path is refused (it would silently mean the current folder);
* a path that resolves to an input of the command (``--data``, the run's ``model.pt``, the fields file
  being drawn) is refused: writing it would destroy that input;
* an existing file inside a run folder (one holding ``run.json`` or ``metrics.json``): the run's own
  outputs (:data:`pdeinv.io.runs.OUTPUTS`: ``training.png``, ``metrics.json``, ``model.pt``, …) and
  whatever else is kept there, is refused unless the command owns that file (``pdeinv show`` redraws
  ``fields.png``);
* missing parent folders are created; a folder that cannot be created or written (read-only, under a
  file, no permission) is refused, naming the folder;
* a file path that is an existing folder is refused (and the other way round).

Every refusal is an :class:`OutputPathError` (a ``ValueError``: the CLI prints its one line and exits
with 2) that names the flag, the path and what to do.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from pathlib import Path


class OutputPathError(ValueError):
    """An output path pdeinv will not write to; the message names the flag and the path."""


#: files whose presence makes a folder a run folder (``pdeinv train --out``)
RUN_MARKERS = ("run.json", "metrics.json")


def _text(path) -> str:
    return os.fspath(path)


def _writable(folder: Path, flag: str, path) -> None:
    """Create ``folder`` (and its parents) and prove it writable, or refuse in one line."""
    where = "" if Path(path) == folder else f": {_text(folder)!r}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        why = "a file is in the way" if isinstance(err, (FileExistsError, NotADirectoryError)) else \
            err.strerror or str(err)
        raise OutputPathError(f"{flag} {_text(path)!r}{where} is not a writable directory ({why}); "
                              f"choose another {flag}") from None


def _not_an_input(path: Path, flag: str, inputs: Iterable) -> None:
    target = path.resolve()
    for name, p in inputs:
        if p and Path(p).resolve() == target:
            raise OutputPathError(f"{flag} {_text(path)!r} is the same file as {name}: writing it would "
                                  f"destroy that input; choose another {flag}")


def run_output(path) -> bool:
    """Whether ``path`` is an existing file of a run folder (one holding :data:`RUN_MARKERS`): the run's
    own results (``training.png``, ``metrics.json``, ``model.pt``, … :data:`pdeinv.io.runs.OUTPUTS`) or
    anything else kept there."""
    path = Path(path)
    return path.is_file() and any((path.parent / m).is_file() for m in RUN_MARKERS)


def output_file(path, flag: str = "out", inputs: Iterable = (), owns: Iterable[str] = (),
                suffixes: Iterable[str] | None = None) -> Path:
    """``path`` as a file this command may write (module docstring), its folder created.

    ``inputs``: ``(name, path)`` pairs the command reads; ``owns``: run-output names the command
    itself writes (allowed inside a run folder); ``suffixes``: the allowed endings (``None``: any).
    """
    if path is None or not _text(path).strip():
        raise OutputPathError(f"{flag} {'' if path is None else _text(path)!r} is empty; expected a path")
    path = Path(path)
    _not_an_input(path, flag, inputs)
    if path.name not in set(owns) and run_output(path):
        raise OutputPathError(f"{flag} {_text(path)!r} is one of that run's own files ({path.name}); "
                              f"writing it would replace the run's result; choose another {flag}")
    suffixes = tuple(suffixes) if suffixes is not None else None
    if suffixes and path.suffix not in suffixes:
        raise OutputPathError(f"{flag} {_text(path)!r}: expected a file name ending in "
                              f"{' or '.join(suffixes)}")
    if path.is_dir():
        raise OutputPathError(f"{flag} {_text(path)!r} is a directory; expected a file name"
                              + (f" ending in {' or '.join(suffixes)}" if suffixes else ""))
    _writable(path.parent, flag, path)
    return path


def output_folder(path, flag: str = "out", inputs: Iterable = ()) -> Path:
    """``path`` as a folder this command may write into (module docstring), created."""
    if path is None or not _text(path).strip():
        raise OutputPathError(f"{flag} {'' if path is None else _text(path)!r} is empty; expected a path")
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputPathError(f"{flag} {_text(path)!r} is a file; expected a directory")
    _not_an_input(path, flag, inputs)
    _writable(path, flag, path)
    return path
