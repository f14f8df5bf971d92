"""One module per ``pdeinv`` subcommand; each exposes ``add_parser(subparsers)``.

``pdeinv.cli`` finds them by themselves (sorted by a module-level ``ORDER``).
``add_parser`` registers the subcommand's arguments and sets ``func`` (``args -> exit code``).
Modules import their heavy dependencies inside ``func`` so ``pdeinv --help`` stays fast.
"""

from __future__ import annotations


class UsageError(Exception):
    """A user mistake the CLI reports in one line (exit code 2)."""


def parse_sets(pairs: list[str]) -> dict:
    """``["kappa=0.02", "mesh=f.msh"]`` -> ``{"kappa": "0.02", ...}`` (problems coerce types)."""
    out = {}
    for item in pairs or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UsageError(f"--set {item!r} is not KEY=VALUE")
        out[key.strip()] = value.strip()
    return out


def add_set_argument(parser) -> None:
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="problem override, e.g. --set kappa=0.02 --set n=32")
