"""One run per output folder: an advisory lock on ``DIR/.lock``.

``with RunLock(out): ...`` is how ``pdeinv train``, ``bench`` and ``stress`` hold their
``--out`` folder for everything they write there. It takes
``fcntl.flock(fd, LOCK_EX | LOCK_NB)`` on ``DIR/.lock`` and writes the holder's PID into
that file. A second run on the same folder does not wait: it raises :class:`FolderLocked`
at once, naming the folder and the holder's PID (the CLI reports it in one line, exit
code 2), and writes nothing -- not even to ``.lock``.

Semantics:

* **Released by the OS.** The lock belongs to the open file, not to the file's
  existence: the kernel drops it when the holder exits in any way, SIGKILL and crashes
  included. A ``.lock`` left behind by a killed run is stale and never blocks the next
  run (e.g. ``--resume``); that run takes it over.
* **Clean folders.** On a normal exit (an exception included) the holder removes
  ``.lock`` while still holding it. A run that locked a file someone removed meanwhile
  notices (the file at ``DIR/.lock`` is no longer the one it locked) and locks the new
  one instead, so the removal never lets two runs in.
* **Advisory.** Only code that takes this lock respects it; other programs can still
  write into the folder. Processes forked by the holder share its open file and keep
  the lock until they exit too.
* **Where.** Local file systems on Linux and macOS (and NFS, where Linux emulates
  ``flock`` with byte-range locks). On platforms without :mod:`fcntl` (Windows) there is
  no lock: :class:`RunLock` does nothing and concurrent runs are not detected.
"""

from __future__ import annotations

import os
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: no lock (see the module docstring)
    fcntl = None

#: the lock file's name inside the folder
NAME = ".lock"


class FolderLocked(RuntimeError):
    """Another process holds the lock on ``folder``; ``pid`` is its PID (None if unreadable)."""

    def __init__(self, folder, pid: int | None):
        self.folder, self.pid = Path(folder), pid
        who = f"PID {pid}" if pid is not None else "PID unknown"
        super().__init__(f"{str(folder)!r} is in use by another pdeinv run ({who} holds {NAME}); "
                         "wait for it to end or choose another output folder")


class RunLock:
    """The lock on ``folder`` (which must exist): ``acquire``/``release``, or ``with RunLock(folder):``."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.path = self.folder / NAME
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> RunLock:
        """Take the lock or raise :class:`FolderLocked` at once; write this PID into ``.lock``."""
        if fcntl is None or self._fd is not None:
            return self
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                pid = _read_pid(fd)
                os.close(fd)
                raise FolderLocked(self.folder, pid) from None
            except BaseException:
                os.close(fd)
                raise
            if _is_current(fd, self.path):
                break
            os.close(fd)  # its holder removed it between our open and flock: lock the new one
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return self

    def release(self) -> None:
        """Remove ``.lock`` (still holding it), then close it, which drops the lock."""
        if self._fd is None:
            return
        try:
            self.path.unlink(missing_ok=True)
        finally:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _is_current(fd: int, path: Path) -> bool:
    """Whether ``fd`` is still the file at ``path`` (not one removed since it was opened)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    own = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)


def _read_pid(fd: int) -> int | None:
    try:
        return int(os.pread(fd, 32, 0).decode().strip())
    except (OSError, ValueError):  # empty (the holder has not written it yet) or garbage
        return None
