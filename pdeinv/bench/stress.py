"""Stress sweeps: run cases that try to break the numerics and classify every outcome.

A case is a value: ``Case(sweep, value, run)`` where ``run() -> dict`` of numbers.
:func:`classify` turns whatever happens into one of

* ``ok`` — finished, every number finite and every watched error ≤ ``bound``;
* ``nan`` — a NaN/Inf in the returned numbers, or :class:`pdeinv.methods.NonFiniteError` raised
  by an update rule (the guard caught it before it spread);
* ``diverged`` — finite numbers but a watched value (keys ending in ``growth`` or ``x_err``)
  above ``bound`` (forward errors are accuracy, not watched: at κT = 1 the exact field is 3e-9
  of u₀, and a coarse BE step is off by orders of magnitude from it without any instability);
* ``failed`` — any other numerical failure on valid input (:func:`pdeinv.errors.numerical_types`:
  no convergence, too many modes, ``LinAlgError``, ``ArpackNoConvergence``), with its type and
  message; checked before ``refused`` because ``LinAlgError`` is a ``ValueError``;
* ``refused`` — any other ``ValueError`` (bad or unsupported setting) with its message;
* ``error`` — any other exception (``MemoryError`` too), with its type and message (a bug or a
  limit to look at). ``KeyboardInterrupt`` stops the sweep. Every case has exactly one outcome.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from ..errors import NonFiniteError, numerical_types

OUTCOMES = ("ok", "nan", "diverged", "failed", "refused", "error")


@dataclass(frozen=True)
class Case:
    """One stress case: ``run()`` returns numbers; watched ones above ``bound`` mean diverged."""

    sweep: str
    value: object
    run: Callable[[], dict]
    bound: float = 10.0


def _numbers(d: dict):
    return ((k, float(v)) for k, v in d.items() if isinstance(v, (int, float)) and not isinstance(v, bool))


def _watched(key: str) -> bool:
    """Stability, not accuracy: amplification and reconstruction/training x-errors."""
    return key.endswith("growth") or key.endswith("x_err")


def _failure(err: Exception) -> tuple[str, str]:
    """``(outcome, message)`` of an exception a case raised (module docstring, in that order)."""
    if isinstance(err, NonFiniteError):
        return "nan", str(err)
    if isinstance(err, numerical_types()):
        return "failed", f"{type(err).__name__}: {err}"
    if isinstance(err, ValueError):
        return "refused", str(err)
    return "error", f"{type(err).__name__}: {err}"


def classify(case: Case) -> dict:
    """Run ``case`` and return ``{"sweep", "value", "outcome", ...numbers or message}``."""
    head = {"sweep": case.sweep, "value": case.value}
    t = time.perf_counter()
    try:
        res = dict(case.run())
    except Exception as err:  # noqa: BLE001 - every outcome is reported, none escapes
        outcome, message = _failure(err)
        return {**head, "outcome": outcome, "message": message, "time_s": time.perf_counter() - t}
    nums = dict(_numbers(res))
    bad = sorted(k for k, v in nums.items() if not math.isfinite(v))
    over = sorted(k for k, v in nums.items() if math.isfinite(v) and _watched(k) and abs(v) > case.bound)
    outcome = "nan" if bad else "diverged" if over else "ok"
    out = {**head, "outcome": outcome, **res, **{k: str(v) for k, v in nums.items() if not math.isfinite(v)}}
    if bad:
        out["message"] = f"non-finite: {', '.join(bad)}"
    elif over:
        out["message"] = f"above {case.bound:g}: {', '.join(over)}"
    out["time_s"] = time.perf_counter() - t
    return out


def run(cases, log=None) -> list[dict]:
    """Classify every case in order; ``log(line)`` after each if given."""
    rows = []
    for case in cases:
        rows.append(classify(case))
        if log:
            log(line(rows[-1]))
    return rows


def line(row: dict) -> str:
    nums = ", ".join(f"{k} {v:.3g}" for k, v in _numbers(row) if k not in ("time_s", "value"))
    msg = "  " + row["message"][:90] if row.get("message") else ""
    return f"{row['sweep']:>10} = {row['value']!s:<8} {row['outcome']:8s} {nums}{msg}"


def counts(rows: list[dict]) -> dict:
    return {o: sum(r["outcome"] == o for r in rows) for o in OUTCOMES}
