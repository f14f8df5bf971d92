"""Atomic files: a reader, a crash or a SIGKILL sees the old file or the new one, never half of one.

:func:`atomic_write` writes into a temporary file in the target's own folder,
flushes and ``fsync``\\ s it, ``os.replace``\\ s it over the target (atomic on POSIX
and Windows) and ``fsync``\\ s the folder, so after it returns the new file also
survives a power loss. The file gets the permissions of a plain ``open``
(``0o666`` minus the umask), not :func:`tempfile.mkstemp`'s ``0o600``. On an error
(a full disk: ``OSError`` ENOSPC) the temporary is removed and the old file stays
as it was. SIGTERM and Ctrl-C arriving during the write are held back until it is done
(:mod:`pdeinv.util.critical`; the command then stops as usual); a SIGKILL leaves the old file. A
temporary left behind by a killed writer is named ``.<name>.<random>.tmp``;
:func:`remove_stale_temporaries` deletes them (one writer per target assumed).
"""

from __future__ import annotations

import csv
import errno
import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from . import critical


def atomic_write(path, write) -> None:
    """``write(fh)`` into a temporary file beside ``path``, fsync, ``os.replace``, fsync the folder; in a
    :func:`~pdeinv.util.critical.section`, so SIGTERM and Ctrl-C wait until the file is in place."""
    with critical.section():
        _atomic_write(Path(path), write)


def _atomic_write(path: Path, write) -> None:
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as err:  # name the target and its folder, never the temporary's random name
        why = "does not exist" if isinstance(err, FileNotFoundError) else "is not writable"
        raise type(err)(f"cannot write {str(path)!r}: its folder {str(path.parent)!r} {why} "
                        f"({err.strerror})") from None
    try:
        if hasattr(os, "fchmod"):
            os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except RuntimeError as err:  # torch.save's C++ writer says a failed write (a full disk) this way
        Path(tmp).unlink(missing_ok=True)
        if "inline_container" in str(err) or "PytorchStreamWriter" in str(err):
            raise OSError(errno.EIO, "the writer failed (a full disk?)", str(path)) from None
        raise
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def _umask() -> int:
    """The process's umask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def fsync_dir(folder: Path) -> None:
    """``fsync`` a folder, so a rename in it is durable (a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # platforms without directory handles (Windows): os.replace is still atomic
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def remove_stale_temporaries(path) -> None:
    """Temporaries of ``path`` left by a killed :func:`atomic_write` (one writer per target assumed)."""
    path = Path(path)
    for stale in path.parent.glob(f".{path.name}.*.tmp"):
        stale.unlink(missing_ok=True)


def write_csv(rows: list[dict], path) -> None:
    """``rows`` as CSV with the union of their keys as header (in first-seen order), atomically."""
    keys = list(dict.fromkeys(k for row in rows for k in row))
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=keys)
    writer.writeheader()
    writer.writerows(rows)
    atomic_write(path, lambda fh: fh.write(text.getvalue().encode()))


def same_row(a: dict, b: dict | None) -> bool:
    """Whether two rows of a history hold the same values (NaN equal to NaN: a rejected step's loss)."""
    def same(u, v):
        return u == v or (isinstance(u, float) and isinstance(v, float) and u != u and v != v)

    return b is not None and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)


class CsvLog:
    """A CSV file of rows that only grow (a run's ``history.csv``). :meth:`write` appends only the rows new
    since its last call, in one write inside a :func:`~pdeinv.util.critical.section`, flushed and
    ``fsync``\\ ed; it rewrites the file atomically (:func:`write_csv`) the first time and whenever the
    header (the union of the rows' keys) would change, the last row it wrote changed or is gone, or the
    file is. The text is the same as a full rewrite's; a call costs its new rows, not the whole history
    (rewriting 20 000 rows every 50 steps was quadratic)."""

    def __init__(self, path):
        self.path, self.keys, self.done, self.last = Path(path), None, 0, None

    def write(self, n: int, rows_from) -> None:
        """The file holds the ``n`` rows ``rows_from(0)``; ``rows_from(i)`` gives rows ``i:`` (only those
        are read where appending does)."""
        if self.keys is not None and 0 < self.done <= n and self.path.is_file():
            tail = rows_from(self.done - 1)
            new = tail[1:]
            if same_row(tail[0], self.last) and {k for row in new for k in row} <= set(self.keys):
                if new:
                    text = io.StringIO(newline="")
                    csv.DictWriter(text, fieldnames=self.keys).writerows(new)
                    with critical.section(), open(self.path, "ab") as fh:
                        fh.write(text.getvalue().encode())
                        fh.flush()
                        os.fsync(fh.fileno())
                self.done, self.last = n, dict(tail[-1])
                return
        rows = rows_from(0)
        write_csv(rows, self.path)
        self.keys = list(dict.fromkeys(k for row in rows for k in row))
        self.done, self.last = len(rows), dict(rows[-1]) if rows else None


def plain(value):
    """``value`` as JSON-able builtins (numpy arrays -> lists, paths -> str), for saving and comparing."""
    def default(v):
        if isinstance(v, np.ndarray):
            return v.tolist()
        if isinstance(v, np.generic):
            return v.item()
        return str(v)  # paths, torch dtypes

    return json.loads(json.dumps(value, default=default))
