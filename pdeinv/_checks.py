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


def shown(value, limit: int = 80) -> str:
    """``repr(value)`` on one line, at most ``limit`` characters (an array's or a module's repr spans
    several)."""
    text = " ".join(repr(value).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def activation_class(activation, name: str = "activation"):
    """``activation`` when it is an ``nn.Module`` class (called once per hidden layer), else a
    ``TypeError`` that names it."""
    from torch import nn

    if not (isinstance(activation, type) and issubclass(activation, nn.Module)):
        raise TypeError(f"{name}={shown(activation)} is not allowed; expected a torch.nn.Module class, "
                        "e.g. torch.nn.Tanh")
    return activation


def float_dtype(value, name: str = "dtype"):
    """``value`` when it is one of torch's real floating-point dtypes (a network factory's ``dtype=``): a
    ``TypeError`` for anything not a ``torch.dtype`` (a string, a numpy type), a ``ValueError`` for an
    integer, boolean or complex one."""
    import torch

    floats = (torch.float16, torch.bfloat16, torch.float32, torch.float64)
    allowed = ", ".join(map(str, floats[:-1])) + f" or {floats[-1]}"
    if not isinstance(value, torch.dtype):
        raise TypeError(f"{name}={shown(value)} is {type(value).__name__}; expected a torch dtype: {allowed}")
    if value not in floats:
        raise ValueError(f"{name}={value!r} is not allowed; expected a floating-point dtype: {allowed}")
    return value


def matrix(value, name: str):
    """``value`` when it is a real ``(m, k)`` array or tensor with ``m, k >= 1`` and finite entries (a
    float tensor or array as given, anything else as float64 numpy): a ``TypeError`` for what is not a real
    numeric array (a string, ``None``, objects), a ``ValueError`` for another shape or a NaN/Inf."""
    import torch

    a = value
    if not (isinstance(a, torch.Tensor) and a.is_floating_point()):
        a = np.asarray(value.detach().cpu() if isinstance(value, torch.Tensor) else value)
        if value is None or a.dtype == object or a.dtype == bool or not np.issubdtype(a.dtype, np.number) \
                or np.iscomplexobj(a):
            kind = "" if value is None else f" of dtype {a.dtype}"
            raise TypeError(f"{name}={shown(value)} is {type(value).__name__}{kind}; expected a real (m, k) "
                            "array")
        if not np.issubdtype(a.dtype, np.floating):
            a = a.astype(float)
    if a.ndim != 2 or 0 in a.shape:
        raise ValueError(f"{name} has shape {tuple(a.shape)}; expected a 2-D (m, k) array with m, k >= 1")
    finite = torch.isfinite(a) if isinstance(a, torch.Tensor) else np.isfinite(a)
    if not bool(finite.all()):
        bad = (~finite).nonzero()
        first = tuple(int(i[0]) for i in bad) if isinstance(bad, tuple) else tuple(int(i) for i in bad[0])
        raise ValueError(f"{name} contains NaN or Inf (first at index {first}); expected finite values")
    return a
