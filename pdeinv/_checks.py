"""Input checks shared by the public entry points.

Every check raises a ``ValueError`` whose message names the offending value and
what is allowed, so a user can act on it without reading a traceback.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable
from numbers import Integral, Real

import numpy as np


def batch(X, n: int, name: str = "X") -> tuple[np.ndarray, bool]:
    """Return ``X`` as a C-contiguous float64 ``(B, n)`` array and whether it was 1-D.

    A 1-D ``(n,)`` input is accepted as a batch of one; the caller squeezes the
    result back with the returned flag.
    """
    torch = sys.modules.get("torch")  # looked up, not imported: no tensor exists before torch is
    if torch is not None and isinstance(X, torch.Tensor):  # a tensor slipped in: say what to use instead
        raise ValueError(
            f"{name} is a torch tensor; operators take numpy arrays "
            "(use pdeinv.apply(operator, x) for torch)"
        )
    A = np.asarray(X)
    if A.dtype == object or not (np.issubdtype(A.dtype, np.number)):
        raise ValueError(f"{name} has dtype {A.dtype}; expected a real numeric array")
    if np.iscomplexobj(A):
        raise ValueError(f"{name} is complex; expected a real array")
    single = A.ndim == 1
    if single:
        A = A[None, :]
    if A.ndim != 2 or A.shape[1] != n:
        raise ValueError(f"{name} has shape {np.shape(X)}; expected (B, {n}) or ({n},)")
    A = np.ascontiguousarray(A, dtype=np.float64)
    if not np.isfinite(A).all():
        bad = np.argwhere(~np.isfinite(A))[0]
        raise ValueError(
            f"{name} contains NaN or Inf (first at index {tuple(int(i) for i in bad)}); "
            "expected finite values"
        )
    return A, single


def flag(value, name: str) -> bool:
    """``True`` or ``False`` (not a truthy string such as ``'yes'``)."""
    if not isinstance(value, bool):
        raise TypeError(f"{name}={value!r} is {type(value).__name__}; expected True or False")
    return value


def positive(value, name: str) -> float:
    """A finite real number > 0."""
    if isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(value):
        raise ValueError(f"{name}={value!r} is not allowed; expected a finite number > 0")
    if value <= 0:
        raise ValueError(f"{name}={value!r} is not allowed; expected a number > 0")
    return float(value)


def nonnegative(value, name: str) -> float:
    """A finite real number >= 0."""
    if isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(value):
        raise ValueError(f"{name}={value!r} is not allowed; expected a finite number >= 0")
    if value < 0:
        raise ValueError(f"{name}={value!r} is not allowed; expected a number >= 0")
    return float(value)


def finite(value, name: str) -> float:
    """A finite real number (any sign)."""
    if isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(value):
        raise ValueError(f"{name}={value!r} is not allowed; expected a finite number")
    return float(value)


def at_least(value, name: str, low: float) -> float:
    """A finite real number >= ``low``."""
    if finite(value, name) < low:
        raise ValueError(f"{name}={value!r} is not allowed; expected a number >= {low:g}")
    return float(value)


def count(value, name: str, minimum: int = 1) -> int:
    """An integer >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < minimum:
        raise ValueError(f"{name}={value!r} is not allowed; expected an integer >= {minimum}")
    return int(value)


def label(value, name: str) -> str:
    """A non-empty, non-blank ``str`` (a rule's ``name``: the run's records and the CLI's messages)."""
    if not isinstance(value, str):
        raise TypeError(f"{name}={value!r} is {type(value).__name__}; expected a non-empty str")
    if not value.strip():
        raise ValueError(f"{name}={value!r} is not allowed; expected a non-empty str")
    return value


#: seeds numpy's SeedSequence and torch.manual_seed both take (the CLI's --seed range)
SEED_MAX = 2**32 - 1


def seed(value, name: str = "seed") -> int:
    """An integer in ``0 .. 2³²−1`` (numpy's own words for ``-1``: "expected non-negative integer")."""
    if isinstance(value, bool) or not isinstance(value, Integral) or not 0 <= value <= SEED_MAX:
        text = repr(value)
        text = text if len(text) <= 60 else text[:57] + "..."
        raise ValueError(f"{name}={text} is not allowed; expected an integer from 0 to {SEED_MAX}")
    return int(value)


def choice(value, name: str, allowed) -> str:
    if value not in allowed:
        raise ValueError(
            f"{name}={value!r} is not allowed; expected one of {', '.join(map(repr, allowed))}"
        )
    return value


def problem(value, name: str = "problem"):
    """A :class:`pdeinv.Problem` (or an object standing in for one), not its name, a path, a number or
    ``None``: a TypeError that says how to load it."""
    import os

    if value is None or isinstance(value, str | bytes | os.PathLike | Real | np.ndarray):
        hint = (f"; load it with pdeinv.load_problem({value!r})" if isinstance(value, str)
                else "; expected a pdeinv.Problem (pdeinv.load_problem(name))")
        raise TypeError(f"{name}={value!r:.80} is {type(value).__name__}, not a pdeinv.Problem{hint}")
    return value


def widths(value, name: str = "hidden") -> tuple[int, ...]:
    """A sequence of layer widths, each an integer >= 1 (``()``: no hidden layer)."""
    if isinstance(value, str | bytes) or not isinstance(value, Iterable):
        raise TypeError(f"{name}={value!r:.80} is {type(value).__name__}; expected a tuple of integer "
                        "widths, e.g. (64, 64)")
    out = tuple(value)
    for w in out:
        if isinstance(w, bool) or not isinstance(w, Integral) or w < 1:
            raise ValueError(f"{name}={out!r:.80} is not allowed; expected integer widths >= 1, "
                             "e.g. (64, 64)")
    return tuple(int(w) for w in out)
