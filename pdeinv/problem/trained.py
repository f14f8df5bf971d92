"""The problem a network was trained on, remembered for the networks pdeinv trains or loads: a network of
one problem takes another's observations whenever their sizes agree (heat_1d's and wave_1d's at n=8), and
would answer with the wrong physics. :func:`mark_trained` records it (the Trainer, :func:`pdeinv.load_run`),
:func:`trained_for` refuses another problem or other settings (``save_run``, ``predict``, ``predictive``).
"""

from __future__ import annotations

import weakref

#: what pdeinv trained or loaded, by network: ``{"problem": name, "settings": {...}}`` (:func:`mark_trained`);
#: weak, so a network no one holds is forgotten with it
_TRAINED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def mark_trained(model, problem) -> None:
    """Record that ``model`` is trained on ``problem`` (its name and settings), which :func:`trained_for`
    compares: the Trainer marks what it trains, :func:`pdeinv.load_run` what it loads. A copy of the network
    (``copy.deepcopy``) is not marked: nothing is refused for it."""
    _TRAINED[model] = {"problem": problem.name, "settings": dict(problem.settings)}


def trained_for(model, problem, name: str = "model") -> None:
    """Refuse ``model`` marked (:func:`mark_trained`) as trained on another problem than ``problem`` or on
    other settings: of the same size it takes the observations, and would answer with another physics'
    network (heat_1d's for wave_1d at n=8). A network the user trained by hand carries no mark."""
    from ..problem.units import unwrap

    seen = _TRAINED.get(model) or _TRAINED.get(unwrap(model)[0])
    if seen is None or problem is None:
        return
    settings = seen["settings"]
    if seen["problem"] != problem.name:
        raise ValueError(f"{name} was trained on problem {seen['problem']!r}, not on {problem.name!r}; "
                         "use it with the problem it was trained on")
    other = [k for k, v in settings.items() if k in problem.settings and differ(problem.settings[k], v)]
    if other:
        k = other[0]
        raise ValueError(f"{name} was trained on {problem.name} with {k}={settings[k]!r}; the problem given "
                         f"has {k}={problem.settings[k]!r}: use it with the settings it was trained on")


def differ(a, b) -> bool:
    """Whether two settings' values differ (arrays and other objects by their repr). Objects whose class
    compares by identity (no ``__eq__`` of its own) carry no value to compare: a new one each ``make()``
    is the same setting (of a module imported again: a class of the same name), so only their classes'
    names are compared."""
    if type(a).__eq__ is object.__eq__ and type(b).__eq__ is object.__eq__:
        return (type(a).__module__, type(a).__qualname__) != (type(b).__module__, type(b).__qualname__)
    try:
        return bool(a != b)
    except (TypeError, ValueError):
        return repr(a) != repr(b)


