"""Disk cache of factorizations: arrays in, arrays out, keyed by a content hash of the inputs.

One function, :func:`cached`::

    arrays = cached("modal", {"M": M, "K": K, "settings": {"tol": 1e-14, ...}}, build)

* ``kind``: a name for the family of entries (also the file name's prefix);
* ``parts``: a dict ``name -> value`` that determines the result: scipy sparse
  matrices (hashed as canonical CSR: data, indices, indptr, shape, dtype), numpy
  arrays (dtype, shape, bytes) and plain values (numbers, strings, bools, None,
  lists/tuples/dicts of them; hashed as sorted JSON, floats by ``repr``, exact);
* ``build() -> dict[str, np.ndarray]``: computes the entry on a miss;
* ``verify(arrays) -> str | None`` (optional): a reason to reject a loaded entry.

The key is the sha256 of ``kind``, :data:`FORMAT` and ``parts``. An entry is
``<folder>/<kind>-<key>.npz`` (uncompressed) holding the arrays and a JSON header
with the key, each array's shape and dtype and a sha256 of their bytes. A loaded
entry is used only if all of these match (and ``verify`` has no objection);
otherwise (corrupt, truncated, another key) it is rebuilt and replaced, with a
warning. Writes go through :func:`pdeinv.util.files.atomic_write` (temporary file and
``os.replace``), so concurrent processes building the same key each end with a
complete entry and readers never see half a file.

The folder is ``$PDEINV_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/pdeinv`` or
``~/.cache/pdeinv``. If it cannot be created or written, one warning per folder is
given and results are computed uncached. ``PDEINV_NO_CACHE=1`` (the CLI's
``--no-cache``) or ``cache=False`` turns the cache off.

The folder is kept under ``$PDEINV_CACHE_MAX_GB`` (default :data:`MAX_GB`): after each
write the least recently used entries (a hit refreshes an entry's time) are deleted until
the rest fits; the entry just written is never deleted.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import warnings
import zipfile
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from .files import atomic_write

#: bump when the file layout or the hashing changes: old entries then simply miss
FORMAT = 1
_HEADER = "__pdeinv_cache__"
#: default size limit of the cache folder in GB (env ``PDEINV_CACHE_MAX_GB``)
MAX_GB = 5.0
_warned: set[str] = set()


def folder() -> Path:
    """The folder (not created): ``$PDEINV_CACHE_DIR``, ``$XDG_CACHE_HOME/pdeinv`` or ``~/.cache/pdeinv``."""
    if os.environ.get("PDEINV_CACHE_DIR"):
        return Path(os.environ["PDEINV_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "pdeinv"


def enabled() -> bool:
    """False when ``PDEINV_NO_CACHE`` is set to anything but ``''`` or ``'0'``."""
    return os.environ.get("PDEINV_NO_CACHE", "") in ("", "0")


def max_bytes() -> float:
    raw = os.environ.get("PDEINV_CACHE_MAX_GB")
    try:
        value = MAX_GB if raw is None else float(raw)
    except ValueError:
        value = float("nan")
    if not value > 0:
        raise ValueError(f"PDEINV_CACHE_MAX_GB={raw!r} is not allowed; expected a number of GB > 0 (an "
                         f"environment variable: unset it for the default {MAX_GB:g})")
    return value * 1e9


#: the name of an entry: ``<kind>-<sha256 hex>.npz`` (:func:`key`)
_ENTRY = re.compile(r"[A-Za-z0-9_]+-[0-9a-f]{64}\.npz")


def evict(where: Path, keep: Path) -> list[Path]:
    """Delete the least recently used entries of ``where`` until it fits :func:`max_bytes`
    (never ``keep``); returns what was deleted. Entries another process removes first are skipped."""
    entries = []
    for path in where.glob("*-*.npz"):
        if not _ENTRY.fullmatch(path.name):  # only this cache's own names (kind-sha256): never a user's file
            continue
        try:
            st = path.stat()
        except OSError:
            continue
        entries.append((st.st_mtime, st.st_size, path))
    total, limit, gone = sum(e[1] for e in entries), max_bytes(), []
    for _, size, path in sorted(entries):
        if total <= limit:
            break
        if path == keep:
            continue
        try:
            path.unlink()
        except OSError:
            continue
        total -= size
        gone.append(path)
    return gone


def _plain(value):
    if isinstance(value, np.generic):  # numpy scalars hash like the Python numbers they equal
        return value.item()
    raise TypeError(type(value).__name__)


def _feed(h, name: str, value) -> None:
    h.update(f"\0{name}\0".encode())
    if sp.issparse(value):
        A = sp.csr_matrix(value, copy=True)
        A.sum_duplicates()
        A.sort_indices()
        h.update(f"csr{A.shape}{A.dtype.str}".encode())
        for arr in (A.data, A.indices.astype(np.int64), A.indptr.astype(np.int64)):
            h.update(np.ascontiguousarray(arr).tobytes())
    elif isinstance(value, np.ndarray):
        h.update(f"nd{value.shape}{value.dtype.str}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    else:
        try:
            h.update(("json" + json.dumps(value, sort_keys=True, default=_plain)).encode())
        except TypeError:
            raise TypeError(f"cache key part {name!r} is a {type(value).__name__}; allowed: sparse matrices, "
                            "numpy arrays, numbers, strings, None and lists/dicts of them") from None


def key(kind: str, parts: dict) -> str:
    """sha256 (hex) of ``kind``, :data:`FORMAT` and ``parts`` (see the module docstring)."""
    h = hashlib.sha256(f"pdeinv-cache/{FORMAT}/{kind}".encode())
    for name in sorted(parts):
        _feed(h, name, parts[name])
    return h.hexdigest()


def _digest(arrays: dict) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        h.update(name.encode())
        h.update(np.ascontiguousarray(arrays[name]).tobytes())
    return h.hexdigest()


def _header(k: str, arrays: dict) -> dict:
    return {"key": k, "format": FORMAT, "digest": _digest(arrays),
            "arrays": {n: [list(a.shape), a.dtype.str] for n, a in arrays.items()}}


def _load(path: Path, k: str, verify) -> dict:
    """The arrays of the entry at ``path``; ``ValueError`` saying why if it is no valid entry for ``k``."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {n: z[n] for n in z.files}
        header = json.loads(str(arrays.pop(_HEADER)))
    except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile) as err:
        raise ValueError(f"unreadable ({type(err).__name__}: {err})") from None
    if header.get("key") != k or header.get("format") != FORMAT:
        raise ValueError("its stored key does not match")
    shapes = {n: [list(a.shape), a.dtype.str] for n, a in arrays.items()}
    if shapes != header.get("arrays"):
        raise ValueError(f"array shapes {shapes} differ from the stored {header.get('arrays')}")
    if _digest(arrays) != header.get("digest"):
        raise ValueError("its content hash does not match")
    reason = verify(arrays) if verify else None
    if reason:
        raise ValueError(reason)
    return arrays


def _warn_once(where: Path, err: OSError) -> None:
    if str(where) not in _warned:
        _warned.add(str(where))
        warnings.warn(f"cache folder {str(where)!r} cannot be written ({err.strerror or err}); "
                      "going on uncached (set PDEINV_CACHE_DIR to a writable folder, or "
                      "PDEINV_NO_CACHE=1)", RuntimeWarning, stacklevel=3)


def has(kind: str, parts: dict) -> bool:
    """Whether an entry for these ``parts`` is stored (not yet verified: :func:`cached` does that)."""
    return enabled() and (folder() / f"{kind}-{key(kind, parts)}.npz").is_file()


def cached(kind: str, parts: dict, build, verify=None, cache: bool = True) -> dict:
    """``build()``'s arrays for these ``parts``, from the disk cache when a valid entry exists.

    A miss (or an invalid entry) calls ``build`` and stores its result; see the module docstring.
    """
    if not kind.replace("_", "").isalnum():
        raise ValueError(f"cache kind {kind!r} is not allowed; expected letters, digits and '_'")
    if not (cache and enabled()):
        return build()
    k = key(kind, parts)
    where = folder()
    path = where / f"{kind}-{k}.npz"
    if path.is_file():
        try:
            arrays = _load(path, k, verify)
            try:
                os.utime(path)  # recently used: the last to be evicted
            except OSError:
                pass
            return arrays
        except ValueError as err:
            warnings.warn(f"cache entry {str(path)!r} is invalid ({err}); rebuilding it",
                          RuntimeWarning, stacklevel=2)
    arrays = {n: np.asarray(a) for n, a in build().items()}
    if _HEADER in arrays:
        raise ValueError(f"build() returned an array named {_HEADER!r}, a name the cache reserves")
    header = np.array(json.dumps(_header(k, arrays)))
    try:
        where.mkdir(parents=True, exist_ok=True)
        atomic_write(path, lambda fh: np.savez(fh, **arrays, **{_HEADER: header}))
        evict(where, path)
    except OSError as err:
        _warn_once(where, err)
    return arrays
