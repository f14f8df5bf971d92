"""``pdeinv problems``: the problems ``pdeinv train`` can find, with their settings and defaults.

Reads each module's ``SETTINGS`` dict (``{name: (default, rule)}``) and the first line of its
docstring; nothing is built, so it takes about a second. A module without ``SETTINGS`` is
listed with "settings: see its make()".
"""

from __future__ import annotations

ORDER = 3


def describe(name: str) -> str:
    """``name: first docstring line`` and one line of ``key=default`` settings."""
    import importlib.util

    from pdeinv.problem.definition import find_module

    path = find_module(name)
    spec = importlib.util.spec_from_file_location(f"pdeinv_problem_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as err:  # a broken module of the user's: listed, not fatal
        return f"{name}: cannot be imported ({type(err).__name__}: {err})"
    doc = (module.__doc__ or "").strip().splitlines()
    settings = getattr(module, "SETTINGS", None)
    shown = ("settings: " + ", ".join(f"{k}={v[0]!r}" for k, v in settings.items())
             if isinstance(settings, dict) else "settings: see its make()")
    return f"{name}: {doc[0] if doc else ''}\n    {shown}\n    from {path}"


def cmd_problems(args) -> int:
    from pdeinv.problem.definition import available

    for name in available():
        print(describe(name))
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("problems", help="list the problems with their settings and defaults")
    p.set_defaults(func=cmd_problems)
