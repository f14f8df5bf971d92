"""The API reference, generated from the docstrings by pdoc: ``python -m pdeinv.util.apidocs DIR``
(``make docs``) writes ``DIR/index.html`` and one page per module of every layer (docs/design.md)."""

from __future__ import annotations

import sys
from pathlib import Path

#: not documented: the command line and benchmarks (``pdeinv --help``), entry scripts
SKIP = ("pdeinv.cli", "pdeinv.bench", "pdeinv.__main__")


def modules() -> list[str]:
    """Every module of the package but :data:`SKIP`, found on disk (``__all__`` lists names, not modules)."""
    import pkgutil

    import pdeinv

    found = [m.name for m in pkgutil.walk_packages(pdeinv.__path__, "pdeinv.")]
    return ["pdeinv", *(m for m in found if not m.startswith(SKIP) and not m.endswith(".__main__"))]


def build(out: Path) -> list[Path]:
    """Write the reference into ``out``; the pages written. Needs ``pdoc`` (the ``test`` extra)."""
    import pdoc

    pdoc.render.configure(docformat="restructuredtext", show_source=False)
    pdoc.pdoc(*modules(), output_directory=Path(out))
    return sorted(Path(out).rglob("*.html"))


if __name__ == "__main__":
    pages = build(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/api"))
    print(f"{len(pages)} pages in {pages[0].parent if pages else '-'}")
