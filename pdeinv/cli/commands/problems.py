"""``pdeinv problems``: the problems ``pdeinv train`` can find, with their settings and defaults.

Reads each module's ``SETTINGS`` dict (``{name: (default, rule)}``) and the first line of its
docstring; nothing is built, so it takes about a second. A module without ``SETTINGS`` is
listed with "settings: see its make()".
"""

from __future__ import annotations

ORDER = 3


def describe(name: str) -> str:
    """``name: first docstring line`` and one line of ``key=default`` settings; a module that cannot be
    imported (it raises, calls ``sys.exit``) or whose ``SETTINGS`` is not ``{name: (default, rule)}`` is one
    line saying so, and the listing goes on."""
    from pdeinv.cli.signals import from_signal
    from pdeinv.problem.definition import find_module, first_line, import_module

    path = find_module(name)
    try:
        module = import_module(path)
    except KeyboardInterrupt as err:
        if from_signal(err):  # the user's Ctrl-C stops the listing
            raise
        return f"{name}: cannot be imported (it raises KeyboardInterrupt)\n    from {path}"
    except SystemExit as err:
        return f"{name}: cannot be imported (it calls sys.exit({err.code!r}))\n    from {path}"
    except BaseException as err:  # noqa: BLE001  a broken module of the user's: listed, not fatal
        return f"{name}: cannot be imported ({type(err).__name__}: {first_line(err, 200)})\n    from {path}"
    if not callable(vars(module).get("make")):
        return f"{name}: has no function make(**overrides), so nothing can be built from it\n    from {path}"
    doc = (module.__doc__ or "").strip().splitlines()
    settings = getattr(module, "SETTINGS", None)
    if settings is None:
        shown = "settings: see its make()"
    elif isinstance(settings, dict) and all(isinstance(v, tuple) and v for v in settings.values()):
        shown = "settings: " + ", ".join(f"{k}={v[0]!r}" for k, v in settings.items())
    else:
        shown = ("settings: its SETTINGS is not a dict of (default, rule) pairs "
                 f"({type(settings).__name__}: {repr(settings)[:80]})")
    return f"{name}: {doc[0] if doc else ''}\n    {shown}\n    from {path}"


def cmd_problems(args) -> int:
    from pdeinv.problem.definition import available

    for name in available():
        print(describe(name))
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("problems", help="list the problems with their settings and defaults")
    p.set_defaults(func=cmd_problems)
