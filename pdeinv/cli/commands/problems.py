"""``pdeinv problems``: the problems ``pdeinv train`` can find, with their settings and defaults.

Reads each module's ``SETTINGS`` dict (``{name: (default, rule)}``) and the first line of its
docstring; nothing is built, so it takes about a second. A module without ``SETTINGS`` is
listed with "settings: see its make()".

The built-in modules are imported here; each of a user's is imported in a process of its own
(:mod:`pdeinv.cli.describe`, up to :data:`AHEAD` at once, started ahead of their turn), so that
one that loops at import (killed after :data:`IMPORT_S` seconds) or ends the process (``os._exit``, a
segfault) is one line of the listing, which goes on.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ORDER = 3

#: the seconds a user's module may take to import before it is killed and listed as not finishing: a listing
#: only guards against a module that never returns, nothing a run computes depends on it
IMPORT_S = 30
#: the user modules imported at once, each in its own process
AHEAD = max(1, min(4, os.cpu_count() or 1))


class _Child:
    """A user's problem module being described in a process of its own (started here)."""

    def __init__(self, name: str, path: Path):
        from pdeinv.util.critical import USER_MODULE_PREFIX

        from .. import describe as _describe

        self.name, self.path = name, path
        read, self._watch = os.pipe()  # the child ends when this closes (the listing done or gone)
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-B", *(["-P"] if sys.version_info >= (3, 11) else []), "-c", _describe.BOOT,
                 _describe.__file__, name, str(path), USER_MODULE_PREFIX, str(read), _json(sys.path)],
                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                pass_fds=(read,), start_new_session=True)  # its own group: killed with what it started
        except BaseException:
            os.close(self._watch)
            raise
        finally:
            os.close(read)
        self.deadline = time.monotonic() + IMPORT_S

    def result(self) -> str:
        """The child's lines, or one line saying it did not finish in time or ended without them."""
        try:
            out, _ = self.proc.communicate(timeout=max(0.0, self.deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            self.kill()
            out, _ = self.proc.communicate()  # it may have finished, a process it started holding the pipe
            if self.proc.returncode != 0 or not out:
                return (f"{self.name}: did not finish importing in {IMPORT_S:g} s (a loop at import?)\n"
                        f"    from {self.path}")
        finally:
            self._close()
        if out:
            return out.decode("utf-8", "replace")
        code = self.proc.returncode
        signalled = code < 0 and -code in _SIGNALS
        how = f"signal {signal.Signals(-code).name}" if signalled else f"exit code {code}"
        return f"{self.name}: its import ended the process ({how})\n    from {self.path}"

    def kill(self) -> None:
        """The child and what it started, killed and reaped (Ctrl-C, SIGTERM, the time limit)."""
        if self.proc.returncode is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)  # not yet reaped: the group is still its own
            except (AttributeError, OSError):  # no process groups (Windows), or gone already
                self.proc.kill()
            self.proc.wait()
        self._close()

    def _close(self) -> None:
        if self._watch is not None:
            os.close(self._watch)
            self._watch = None


_SIGNALS = {int(s) for s in signal.Signals}


def _json(value) -> str:
    import json

    return json.dumps(value)


def _builtin(path: Path) -> bool:
    from pdeinv.problem.definition import builtin_dir

    return Path(path).resolve().is_relative_to(builtin_dir().resolve())


def _in_process(name: str, path: Path) -> str:
    """The lines of a built-in module, imported here (trusted: pdeinv's own)."""
    from pdeinv.cli.signals import from_signal
    from pdeinv.problem.definition import import_module

    from ..describe import summary

    return summary(name, path, import_module, lambda err: not from_signal(err))


def describe(name: str) -> str:
    """``name: first docstring line`` and one line of ``key=default`` settings; a module that cannot be
    imported (it raises, calls ``sys.exit``, loops, ends the process) or whose ``SETTINGS`` is not
    ``{name: (default, rule)}`` is one line saying so, and the listing goes on."""
    from pdeinv.problem.definition import find_module

    path = find_module(name)
    if _builtin(path):
        return _in_process(name, path)
    child = _Child(name, path)
    try:
        return child.result()
    finally:
        child.kill()


def cmd_problems(args) -> int:
    from pdeinv.problem.definition import available, find_module

    paths = {name: find_module(name) for name in available()}
    users = iter([name for name, path in paths.items() if not _builtin(path)])
    children: dict[str, _Child] = {}
    try:
        for name, path in paths.items():
            while len(children) < AHEAD and (nxt := next(users, None)) is not None:
                children[nxt] = _Child(nxt, paths[nxt])
            print(children.pop(name).result() if name in children else _in_process(name, path), flush=True)
    finally:  # Ctrl-C, SIGTERM: no child outlives the listing
        for child in children.values():
            child.kill()
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("problems", help="list the problems with their settings and defaults")
    p.set_defaults(func=cmd_problems)
