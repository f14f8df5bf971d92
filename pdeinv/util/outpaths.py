"""One policy for every path pdeinv writes to (``train --out``, ``predict --out/--vtu``, ``show --png``,
``classical --out``, :func:`pdeinv.save_run`), checked before any work:

* every path is **resolved first** (symbolic links, ``..``; :func:`resolve`): ``out/new/../../runs/h1``,
  where ``out/new`` does not exist yet, is ``runs/h1``, and a link to a run is that run; every check
  below and the write itself use the resolved path, and a refusal names both;
* an empty path is refused (it would silently mean the current folder);
* a path that resolves to an input of the command (``--data``, the run's ``model.pt``, the fields file
  being drawn) is refused: writing it would destroy that input;
* **a run folder** is one pdeinv marked as its own (:func:`is_run_folder`: the :data:`RUN_MARKER` file
  ``pdeinv train`` writes before its first file, or a ``run.json`` with pdeinv's own ``"format"`` key),
  never merely a folder holding a file named ``metrics.json``. ``train --out`` (:func:`run_folder`)
  takes a new or empty folder, or a run folder; a run folder holding a run's files only with
  ``--overwrite`` (which then removes only :data:`pdeinv.io.runs.OUTPUTS`) or ``--resume``. Any other
  non-empty folder is refused, ``--overwrite`` or not, naming what it holds;
* a single file (:func:`output_file`): one of a run's own files (:data:`RUN_OUTPUTS`, its
  marker and lock, in a run folder) is refused unless the command owns that file (``pdeinv show`` redraws
  ``fields.png``); any other existing file (an earlier prediction kept in a run folder included) is
  replaced only with ``--overwrite``; something that is not a regular file (a device, a pipe) never;
* missing parent folders are created; a folder that cannot be created or written (read-only, under a
  file, no permission) is refused, naming the folder;
* a file path that is an existing folder is refused (and the other way round);
* a sweep's folder (``bench --out``, ``stress --out``: :func:`output_folder` with ``record``) is new, empty,
  or one of that sweep's earlier results; a run folder or a user's folder is refused, naming what it holds.

Every refusal is an :class:`OutputPathError` (a ``ValueError``: the CLI prints its one line and exits
with 2) that names the flag, the path and what to do.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path


class OutputPathError(ValueError):
    """An output path pdeinv will not write to; the message names the flag and the path."""


#: the file ``pdeinv train`` writes into its ``--out`` folder before any other: the folder is a pdeinv run
RUN_MARKER = ".pdeinv-run"
#: ``run.json``'s ``"format"`` (:mod:`pdeinv.io.runs`): a run folder written before :data:`RUN_MARKER` existed
RUN_FORMAT = "pdeinv-run"
#: every file ``pdeinv train`` writes into a run folder (:data:`pdeinv.io.runs.OUTPUTS` is this list)
RUN_OUTPUTS = ("metrics.json", "history.csv", "training.png", "model.pt", "run.json", "posterior.npz",
               "checkpoint.pt", "fields.vtu", "fields.xdmf", "fields.png", "sensors.vtu")
#: what an otherwise empty folder may hold: a killed run's lock (:mod:`pdeinv.util.runlock`), Finder's file
IGNORED = (".lock", ".DS_Store")
#: names a refusal lists before "and N more"
LISTED = 6


def _text(path) -> str:
    return os.fspath(path)


def _named(flag: str, path, target: Path) -> str:
    """``--out 'a/../b'`` and, where it differs, what it resolves to: ``(= '/home/u/b')``."""
    text = _text(path)
    plain = ".." not in Path(text).parts and os.path.abspath(text) == str(target)
    return f"{flag} {text!r}" + ("" if plain else f" (= {str(target)!r})")


def _empty(path, flag: str) -> None:
    if path is None or not _text(path).strip():
        raise OutputPathError(f"{flag} {'' if path is None else _text(path)!r} is empty; expected a path")


def resolve(path, flag: str = "out") -> Path:
    """``path`` absolute, with its links followed and its ``..`` taken, whether or not it exists: the
    file or folder a write would reach. ``out/new/../../runs/h1`` is ``runs/h1`` even where ``out/new``
    does not exist (where the operating system would create ``out/new`` on the way and then reach
    ``runs/h1`` anyway)."""
    _empty(path, flag)
    target = Path(os.path.realpath(os.path.abspath(os.fspath(path))))
    if any(os.path.islink(part) for part in (target, *target.parents)):  # realpath stops inside a loop
        raise OutputPathError(f"{flag} {_text(path)!r} leads into a loop of symbolic links (at "
                              f"{str(target)!r}); choose another {flag}")
    longest = max((p for p in target.parts), key=lambda p: len(os.fsencode(p)))
    if len(os.fsencode(longest)) > NAME_MAX:
        raise OutputPathError(f"{flag} {_text(path)[:60]!r}…: the name {longest[:20]!r}… is "
                              f"{len(os.fsencode(longest))} bytes long; expected at most {NAME_MAX} (the "
                              f"file system's limit); choose another {flag}")
    given = Path(os.path.abspath(os.fspath(path)))
    if len(os.fsencode(str(given))) >= PATH_MAX:
        raise OutputPathError(f"{flag} {_text(path)[:60]!r}… is {len(os.fsencode(str(given)))} bytes long as "
                              f"a full path; expected fewer than {PATH_MAX} (the system's limit); choose "
                              f"another {flag}")
    for part in (*reversed(given.parents), given):  # mkdir -p refuses a dangling link; so does pdeinv
        if os.path.islink(part) and not os.path.exists(part):
            raise OutputPathError(f"{flag} {_text(path)!r} goes through {str(part)!r}, a symbolic link to "
                                  f"{os.readlink(part)!r}, which does not exist; create it or choose "
                                  f"another {flag}")
    return target


def is_run_folder(folder) -> bool:
    """Whether ``folder`` holds a pdeinv run: :data:`RUN_MARKER`, or a ``run.json`` whose ``"format"``
    is pdeinv's (a folder with a user's own ``metrics.json`` or ``run.json`` is not one)."""
    folder = Path(folder)
    if (folder / RUN_MARKER).is_file():
        return True
    try:
        record = json.loads((folder / "run.json").read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(record, dict) and record.get("format") == RUN_FORMAT


def mark_run_folder(folder) -> None:
    """Write :data:`RUN_MARKER` into ``folder`` (before a run's first file)."""
    marker = Path(folder) / RUN_MARKER
    if not marker.is_file():
        marker.write_text(json.dumps({"format": RUN_FORMAT}) + "\n")


def contents(folder) -> list[str]:
    """The names in ``folder`` (sorted, :data:`IGNORED` left out)."""
    return sorted(p.name for p in Path(folder).iterdir() if p.name not in IGNORED)


#: a listed name longer than this is cut (a cache folder's 64-digit hashes made a 767-character line)
NAME_CHARS = 32
#: the longest file or folder name, in bytes (NAME_MAX of the usual Linux and macOS file systems)
NAME_MAX = 255
#: the bytes of a full path, its terminating zero included (PATH_MAX of Linux; macOS's is 1 024)
PATH_MAX = 4096


def _listing(names: list[str]) -> str:
    more = len(names) - LISTED
    cut = [n if len(n) <= NAME_CHARS else n[:NAME_CHARS - 1] + "…" for n in names[:LISTED]]
    return ", ".join(cut) + (f" and {more} more" if more > 0 else "")


def _writable(folder: Path, flag: str, named: str, target: Path) -> None:
    """Create ``folder`` (and its parents) and prove it writable, or refuse in one line."""
    where = "" if target == folder else f": {str(folder)!r}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        why = "a file is in the way" if isinstance(err, (FileExistsError, NotADirectoryError)) else \
            "no file can be made in it" if isinstance(err, FileNotFoundError) and folder.is_dir() else \
            err.strerror or str(err)  # /proc: a folder that exists, whose new files "do not exist"
        raise OutputPathError(f"{named}{where} is not a writable directory ({why}); "
                              f"choose another {flag}") from None


def _creatable(folder: Path, flag: str, named: str) -> None:
    """Refuse in one line, leaving nothing behind, a ``folder`` that cannot be created: the nearest existing
    path above it is a file (``--out notes.txt/sub``) or a folder in which no folder can be made."""
    above = folder
    while not above.exists() and above != above.parent:
        above = above.parent
    if not above.is_dir():
        raise OutputPathError(f"{named} is not a writable directory (a file is in the way: {str(above)!r}); "
                              f"choose another {flag}")
    try:
        tempfile.TemporaryDirectory(dir=above).cleanup()
    except OSError as err:
        raise OutputPathError(f"{named} is not a writable directory ({err.strerror or err} in "
                              f"{str(above)!r}); choose another {flag}") from None


def _not_an_input(target: Path, named: str, flag: str, inputs: Iterable) -> None:
    for name, p in inputs:
        try:
            same = bool(p and _text(p).strip()) and resolve(p, name) == target
        except OutputPathError:  # a dangling link, a loop: no file the output could be; its reader says so
            same = False
        if same:
            raise OutputPathError(f"{named} is the same file as {name}: writing it would "
                                  f"destroy that input; choose another {flag}")


def _run_file(target: Path) -> bool:
    """Whether ``target`` is a file ``pdeinv train`` writes in a run folder (:data:`RUN_OUTPUTS`, its marker,
    its lock): never replaced by another command."""
    return target.name in {*RUN_OUTPUTS, RUN_MARKER, *IGNORED} and is_run_folder(target.parent)


def run_output(path) -> bool:
    """Whether ``path`` (resolved) is an existing file of a run folder (:func:`is_run_folder`): the run's
    own results (``training.png``, ``metrics.json``, ``model.pt``, … :data:`pdeinv.io.runs.OUTPUTS`) or
    anything else kept there."""
    path = resolve(path)
    return path.is_file() and is_run_folder(path.parent)


def output_file(path, flag: str = "out", inputs: Iterable = (), owns: Iterable[str] = (),
                suffixes: Iterable[str] | None = None, overwrite: bool = False) -> Path:
    """``path`` resolved (:func:`resolve`), as a file this command may write (module docstring), its
    folder created; write the path returned.

    ``inputs``: ``(name, path)`` pairs the command reads; ``owns``: run-output names the command
    itself writes (replaced inside a run folder); ``suffixes``: the allowed endings (``None``: any);
    ``overwrite``: an existing file outside a run folder may be replaced (``--overwrite``).
    """
    target = resolve(path, flag)
    named = _named(flag, path, target)
    if str(os.fspath(path)).endswith(("/", os.sep)):  # resolve() drops the slash that names a folder
        raise OutputPathError(f"{named} ends in '/', a folder; expected a file name")
    _not_an_input(target, named, flag, inputs)
    own_file = target.is_file() and _run_file(target)  # one look at the folder's marker
    owned = own_file and target.name in set(owns)
    if own_file and not owned:
        raise OutputPathError(f"{named} is one of a run's own files ({target.name}) in the run folder "
                              f"{str(target.parent)!r}; writing it would replace that run's result; choose "
                              f"another {flag}")
    suffixes = tuple(suffixes) if suffixes is not None else None
    if suffixes and target.name.lower() in suffixes:
        raise OutputPathError(f"{named} is an ending alone; expected a name before it, e.g. "
                              f"'results{target.name}'")
    if suffixes and target.suffix.lower() not in suffixes:  # p.NPZ, s.PNG: the same formats
        raise OutputPathError(f"{named}: expected a file name ending in {' or '.join(suffixes)}")
    if target.is_dir():
        raise OutputPathError(f"{named} is a directory; expected a file name"
                              + (f" ending in {' or '.join(suffixes)}" if suffixes else ""))
    if target.exists() and not target.is_file():
        raise OutputPathError(f"{named} is not a regular file (a device, a pipe or a socket); "
                              f"choose another {flag}")
    if target.is_file() and not owned and not overwrite:
        how = "--overwrite" if flag.startswith("--") else "overwrite=True"  # a flag, or a Python argument
        raise OutputPathError(f"{named} exists; pass {how} to replace it, or choose another {flag}")
    _writable(target.parent, flag, named, target)
    return target


def record_format(record: str) -> str:
    """The ``"format"`` a sweep writes into its ``record`` (``bench.json``: ``"pdeinv-bench"``), by which
    :func:`output_folder` tells its earlier results from a user's file of the same name."""
    return f"pdeinv-{Path(record).stem}"


def _own_record(path: Path) -> bool:
    try:
        held = json.loads(path.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(held, dict) and held.get("format") == record_format(path.name)


def output_folder(path, flag: str = "out", inputs: Iterable = (), record: str | None = None,
                  replace: bool = False) -> Path:
    """``path`` resolved (:func:`resolve`), as a folder this command may write into (module docstring),
    created. ``record``: the file a sweep writes (``bench.json``, ``stress.json``): the folder must then be
    new, empty, or, with ``replace`` (``--overwrite``), hold that command's earlier results (its
    ``record``, recognised by its ``"format"``, :func:`record_format`; whose files it replaces); a run
    folder or any other non-empty folder (a user's own file of the record's name too) is refused, naming
    what it holds."""
    target = resolve(path, flag)
    named = _named(flag, path, target)
    if target.exists() and not target.is_dir():
        raise OutputPathError(f"{named} is a file; expected a directory")
    held = contents(target) if record and target.is_dir() else []
    if held and (record not in held or not _own_record(target / record) or is_run_folder(target)):
        why = (f"its {record} is not one this command wrote" if record in held
               else "it is not a folder of this command's earlier results")
        raise OutputPathError(f"{named} holds {_listing(held)}: {why}; its results go only into a new or "
                              f"empty folder, or one of its earlier results; choose another {flag}")
    if held and not replace:
        raise OutputPathError(f"{named} holds this command's earlier results ({_listing(held)}); pass "
                              f"--overwrite to replace them, or choose another {flag}")
    _not_an_input(target, named, flag, inputs)
    _writable(target, flag, named, target)
    return target


def run_folder(path, flag: str = "out", replace: bool = False, outputs: Iterable[str] = (),
               create: bool = True) -> Path:
    """``path`` resolved (:func:`resolve`) as the folder of a pdeinv run (``pdeinv train --out``,
    :func:`pdeinv.save_run`): new, empty, or a run folder (:func:`is_run_folder`) whose ``outputs``
    (:data:`pdeinv.io.runs.OUTPUTS`) may be replaced only with ``replace`` (``--overwrite``,
    ``--resume``); any other non-empty folder is refused, naming what it holds. ``create``: create it
    now (else only check it; :func:`output_folder` creates it later)."""
    target = resolve(path, flag)
    named = _named(flag, path, target)
    if target.exists() and not target.is_dir():
        raise OutputPathError(f"{named} is a file; expected a directory")
    held = contents(target) if target.is_dir() else []
    if held and not is_run_folder(target):
        raise OutputPathError(f"{named} holds {_listing(held)} and is not a pdeinv run folder (no "
                              f"{RUN_MARKER}, no run.json of pdeinv's): pdeinv writes a run only into a new "
                              f"or empty folder, and --overwrite replaces only a pdeinv run; choose another "
                              f"{flag}")
    found = [name for name in outputs if (target / name).is_file()]
    if found and not replace:
        raise OutputPathError(f"{named}: {found[0]} exists; choose another {flag}, pass --resume to "
                              f"continue that run or --overwrite to replace it (a previous run's files: "
                              f"{', '.join(found)})")
    if create:
        _writable(target, flag, named, target)
    else:
        _creatable(target, flag, named)
    return target
