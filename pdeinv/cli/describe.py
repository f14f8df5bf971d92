"""The lines ``pdeinv problems`` prints for one problem module, and the child process that imports a user's
module to write them (:mod:`pdeinv.cli.commands.problems`).

Standard library only, and nothing of pdeinv at import: the child runs this file by its path
(:data:`BOOT`), so its start-up costs a bare interpreter's (about 0.05 s), not pdeinv's (numpy, torch),
unless the module imports them itself.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path

#: what the child runs (``python -c BOOT THIS_FILE ...``): this file, by its path, as ``__main__``
BOOT = "import runpy, sys; runpy.run_path(sys.argv[1], run_name='__main__')"


def first_line(err: BaseException, n: int = 200) -> str:
    """:func:`pdeinv.problem.definition.first_line`, here without the imports of that module (torch)."""
    try:
        text = str(err)
    except Exception as inner:  # noqa: BLE001  any failure of a user's __str__
        return f"(its message cannot be printed: {type(inner).__name__})"
    return (text.strip().splitlines() or [""])[0][:n]


def summary(name: str, path: Path, load: Callable[[Path], object],
            own_interrupt: Callable[[BaseException], bool]) -> str:
    """``name: first docstring line`` and one line of ``key=default`` settings of the module ``load(path)``
    executes; a module that cannot be imported (it raises, calls ``sys.exit``) or whose ``SETTINGS`` is not
    ``{name: (default, rule)}`` is one line saying so. A ``KeyboardInterrupt`` that is not
    ``own_interrupt`` (the user's Ctrl-C) propagates."""
    try:
        module = load(path)
    except KeyboardInterrupt as err:
        if not own_interrupt(err):  # the user's Ctrl-C stops the listing
            raise
        return f"{name}: cannot be imported (it raises KeyboardInterrupt)\n    from {path}"
    except SystemExit as err:
        return f"{name}: cannot be imported (it calls sys.exit({err.code!r}))\n    from {path}"
    except BaseException as err:  # noqa: BLE001  a broken module of the user's: listed, not fatal
        return f"{name}: cannot be imported ({type(err).__name__}: {first_line(err)})\n    from {path}"
    if not callable(vars(module).get("make")):
        return f"{name}: has no function make(**overrides), so nothing can be built from it\n    from {path}"
    doc = (module.__doc__ or "").strip().splitlines()
    settings = getattr(module, "SETTINGS", None)
    if settings is None:
        shown = "settings: see its make()"
    elif isinstance(settings, dict) and all(isinstance(v, tuple) and v for v in settings.values()):
        shown = "settings: " + ", ".join(f"{k}={v[0]!r}" for k, v in settings.items())
    else:
        shown = ("settings: its SETTINGS is not a dict of (default, rule) pairs "
                 f"({type(settings).__name__}: {repr(settings)[:80]})")
    return f"{name}: {doc[0] if doc else ''}\n    {shown}\n    from {path}"


def _load_under(prefix: str) -> Callable[[Path], object]:
    """:func:`pdeinv.problem.definition.import_module` (the module named ``prefix`` + its stem)."""
    import importlib.util

    def load(path: Path):
        spec = importlib.util.spec_from_file_location(f"{prefix}{path.stem}", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


def _exit_when_orphaned(fd: int) -> None:
    """End this process as soon as ``fd`` (the read end of a pipe only the parent writes to) reads end of
    file: the parent is gone (even by SIGKILL), and a module looping at import must not outlive it."""
    import threading

    def watch():
        while os.read(fd, 1):
            pass
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def child(argv: list[str]) -> None:
    """The child's work: ``argv`` = name, path, module-name prefix, watch fd, the parent's ``sys.path``
    (JSON). Writes :func:`summary` to its stdout (UTF-8) and ends at once (no atexit, no threads of the
    module awaited); what the module itself prints goes to stderr, which the parent drops."""
    import json
    import signal

    name, path, prefix, fd, search = argv
    _exit_when_orphaned(int(fd))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops it: a Ctrl-C here is the module's own
    sys.path[:] = json.loads(search)  # what the module would see in the parent
    sys.path.insert(0, str(Path(path).parent))  # and its siblings, as pdeinv.load_problem adds them
    out = os.dup(1)
    os.dup2(2, 1)  # the module's prints, even at the C level, stay out of the result
    sys.stdout = sys.stderr
    try:
        text = summary(name, Path(path), _load_under(prefix), lambda err: True)
    except BaseException as err:  # noqa: BLE001  e.g. a user's __repr__ of SETTINGS raising
        text = f"{name}: cannot be listed ({type(err).__name__}: {first_line(err)})\n    from {path}"
    data = text.encode("utf-8", "backslashreplace")
    while data:
        data = data[os.write(out, data):]
    os._exit(0)


if __name__ == "__main__":
    child(sys.argv[2:])
