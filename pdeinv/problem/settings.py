"""Problem overrides: defaults, type coercion (for CLI strings) and checks.

A problem module declares its settings as ``{name: (default, rule)}``; the rule
turns a user value (possibly the string from ``--set name=value``) into a valid
one or raises ``ValueError`` naming the value and what is allowed.
"""

from __future__ import annotations

import math
import numbers
import os

from .. import _checks

#: the largest integer setting (``n``, ``steps``, ...): beyond int32 it is a typo and overflows C integers
INT_MAX = 2**31 - 1
#: the largest magnitude of a real setting (``kappa``, ``T``, ``noise``, ...): its square stays finite
FLOAT_MAX = 1e150


def _in_range(value, name, text):
    """``value`` unless an integer beyond :data:`INT_MAX` or a real beyond :data:`FLOAT_MAX` in
    magnitude, or a nonzero real below ``1 / FLOAT_MAX`` (``kappa=1e-320`` overflowed to a traceback
    where the physics divides by it; ``1e-400``, read as 0, too); NaN and Inf are left to the rule's own
    check, which names them."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and abs(value) > INT_MAX:
        raise ValueError(f"{name}={text!r} is out of range; expected an integer of at most {INT_MAX}")
    if isinstance(value, float) and math.isfinite(value) and abs(value) > FLOAT_MAX:
        raise ValueError(f"{name}={text!r} is out of range; expected a number of magnitude at most "
                         f"{FLOAT_MAX:g}")
    underflow = value == 0 and isinstance(text, str) and any(c in "123456789" for c in
                                                             text.lower().partition("e")[0])  # 1e-400
    if isinstance(value, float) and (0 < abs(value) < 1 / FLOAT_MAX or underflow):
        raise ValueError(f"{name}={text!r} is out of range; expected a magnitude of at least "
                         f"{1 / FLOAT_MAX:g} (or 0, where {name} may be 0)")
    return value


def _number(cast, check):
    def rule(value, name):
        text = value
        if isinstance(value, numbers.Integral) and not isinstance(value, int):  # numpy's integers
            value = int(value)
        elif isinstance(value, numbers.Real) and not isinstance(value, int | float):  # np.float32(8)
            value = float(value)
        if isinstance(value, str):
            if "_" in value or not value.isascii():  # Python's float reads '16_0' as 160 and '１６' as 16
                raise ValueError(f"{name}={value!r} is not a number; expected plain digits (e.g. 16, 0.01, "
                                 "1e-3)")
            try:
                value = float(value)  # "1e2" is a number too; an int rule takes it if it is whole
            except ValueError:
                raise ValueError(f"{name}={value!r} is not a number") from None
            if cast is int and not value.is_integer():
                kind = "is not a whole number" if math.isfinite(value) else "is not finite"
                raise ValueError(f"{name}={value!r} is not allowed ({value:g} {kind}); expected an integer")
        if cast is int and isinstance(value, float) and value.is_integer():
            value = int(value)
        return check(_in_range(value, name, text), name)

    return rule


positive_int = _number(int, _checks.count)
nonnegative_int = _number(int, lambda value, name: _checks.count(value, name, minimum=0))
positive = _number(float, _checks.positive)
nonnegative = _number(float, _checks.nonnegative)


def _below_one(value, name):
    value = _checks.positive(value, name)
    if value >= 1:
        raise ValueError(f"{name}={value!r} is not allowed; expected a relative cut 0 < {name} < 1")
    return value


#: a relative tolerance or cut: a number in (0, 1)
fraction = _number(float, _below_one)


def one_of(*allowed):
    """A rule taking one of ``allowed``; a name in other letter case (``BE`` for ``be``) is the one it
    spells when exactly one matches."""
    def rule(value, name):
        text = value.lower() if isinstance(value, str) else None
        same = [a for a in allowed if isinstance(a, str) and a.lower() == text]
        return _checks.choice(same[0] if len(same) == 1 else value, name, allowed)

    return rule


def optional_path(value, name):
    """``None`` or the path of an existing file (a directory is refused by name)."""
    if value is None or value == "":
        return None
    if not isinstance(value, (str, os.PathLike)):
        raise ValueError(f"{name}={value!r} is not allowed; expected a file path")
    if os.path.isdir(value):
        raise ValueError(f"{name}={os.fspath(value)!r} is a directory; expected a file")
    if not os.path.isfile(value):
        raise FileNotFoundError(f"{name}={os.fspath(value)!r}: no such file")
    return os.fspath(value)


def resolve(spec: dict, overrides: dict, problem: str) -> dict:
    """Merge ``overrides`` into the defaults of ``spec``, checking every value. ``spec`` maps each name to a
    ``(default, rule)`` pair; anything else (a module's ``SETTINGS = dict(n=16)``) is a ``TypeError`` naming
    the entry, not an unpacking error from inside this function."""
    from collections.abc import Mapping

    for arg, value in (("spec", spec), ("overrides", overrides)):
        if not isinstance(value, Mapping):
            raise TypeError(f"settings.resolve({arg}={value!r:.60}) is {type(value).__name__}; expected a "
                            "dict (the problem's SETTINGS, and the overrides of make(**overrides))")
    for name, entry in spec.items():
        if not (isinstance(entry, tuple) and len(entry) == 2 and callable(entry[1])):
            raise TypeError(f"settings of {problem!r}: {name!r}: {entry!r} is not a (default, rule) pair; "
                            f"expected e.g. {name!r}: (32, settings.positive_int) (docs/problems.md)")
    unknown = sorted(set(overrides) - set(spec))
    if unknown:
        raise ValueError(
            f"unknown setting(s) {', '.join(map(repr, unknown))} for problem {problem!r}; "
            f"allowed: {', '.join(sorted(spec))}"
        )
    out = {}
    for name, (default, rule) in spec.items():
        value = overrides.get(name, default)
        if default is None and isinstance(value, str) and value.strip() == "None":
            value = None  # the default as `pdeinv problems` lists it (--set kappa=None)
        out[name] = rule(value, name) if name in overrides else value
    return out
