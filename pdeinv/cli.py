"""Command line: ``pdeinv demo | train``, one module per subcommand in :mod:`pdeinv.commands`.

Errors a user can fix (bad settings, missing files) end with exit code 2 and a
one-line message on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
import sys

from .commands import UsageError, demo, parse_sets, train

__all__ = ["UsageError", "build_parser", "main", "parse_sets"]

#: subcommand modules, in the order ``pdeinv --help`` lists them
COMMANDS = (demo, train)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pdeinv", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.add_parser(sub)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (UsageError, ValueError, FileNotFoundError, NotImplementedError) as err:
        print(f"pdeinv {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
