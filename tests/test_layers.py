"""The folders of ``pdeinv`` are layers (docs/design.md, "Layout"): no module imports from a later one,
neither at module level nor inside a function; the package root holds no module but ``__init__``,
``__main__``, ``errors`` and ``_checks``; no folder holds more than 12 modules."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import pdeinv

ROOT = Path(pdeinv.__file__).parent
#: the layers, upstream first (folders of one layer may import each other)
LAYERS = [("errors", "_checks", "util"), ("fem",), ("physics",), ("inverse",), ("nets",), ("problem",),
          ("methods", "posterior"), ("training",), ("io",), ("cli", "bench")]
RANK = {name: i for i, names in enumerate(LAYERS) for name in names}


def imported(path: Path, source: str | None = None) -> list[tuple[int, str]]:
    """``(line, top-level pdeinv part)`` of every pdeinv import in ``path`` (or in ``source``, read as
    if it were at ``path``), relative or absolute."""
    rel = path.relative_to(ROOT).with_suffix("").parts
    package = ["pdeinv", *rel[:-1]]
    found = []
    for node in ast.walk(ast.parse(path.read_text() if source is None else source)):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                module = base + (node.module.split(".") if node.module else [])
            elif node.module and node.module.split(".")[0] == "pdeinv":
                module = node.module.split(".")
            else:
                continue
            targets = [[*module, a.name] for a in node.names] if len(module) == 1 else [module]
        elif isinstance(node, ast.Import):
            targets = [a.name.split(".") for a in node.names if a.name.split(".")[0] == "pdeinv"]
        else:
            continue
        found += [(node.lineno, t[1]) for t in targets if len(t) > 1]
    return found


def modules():
    return sorted(p for p in ROOT.rglob("*.py") if p.relative_to(ROOT).parts[0] in RANK)


@pytest.mark.parametrize("path", modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_import_runs_upstream(path):
    layer = path.relative_to(ROOT).parts[0]
    upward = [f"line {line}: {layer} imports pdeinv.{part}" for line, part in imported(path)
              if part in RANK and RANK[part] > RANK[layer]]
    assert not upward, f"{path.relative_to(ROOT)}: " + "; ".join(upward)


def test_the_checker_sees_an_upward_import():
    """The test above can fail: a function-level import of the trainer from a physics module."""
    probe = ROOT / "physics" / "probe.py"
    assert imported(probe, "def f():\n    from ..training import trainer\n") == [(2, "training")]
    assert imported(probe, "import pdeinv.io.runs\nfrom pdeinv import nets\n") == [(1, "io"), (2, "nets")]


def test_the_root_holds_only_entry_points_and_errors():
    root = sorted(p.name for p in ROOT.glob("*.py"))
    assert root == ["__init__.py", "__main__.py", "_checks.py", "errors.py"]
    assert {p.name for p in ROOT.iterdir() if p.is_dir() and (p / "__init__.py").exists()} == set(RANK) - {
        "errors", "_checks"}


def test_no_folder_holds_more_than_twelve_modules():
    big = {str(d.relative_to(ROOT)): n for d in [ROOT, *ROOT.rglob("*")] if d.is_dir()
           and (n := len(list(d.glob("*.py")))) > 12}
    assert not big, big


def test_no_function_is_longer_than_sixty_lines():
    """Functions with their docstrings; a longer one does more than one thing (issue 33)."""
    long = [f"{p.relative_to(ROOT)}:{n.lineno} {n.name} ({n.end_lineno - n.lineno + 1} lines)"
            for p in ROOT.rglob("*.py") for n in ast.walk(ast.parse(p.read_text()))
            if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef) and n.end_lineno - n.lineno >= 60]
    assert not long, long


def test_capabilities_are_declared_not_probed():
    """At most 15 lines of ``getattr``/``hasattr``/``inspect.signature`` outside ``cli/`` and ``io/``
    (issue 33: 111 before): the PEP 562 lazy-import hooks and optional attributes of objects pdeinv
    does not own (``os``, solvers, a user's rule or problem module); everything else is declared."""
    import re

    probe = re.compile(r"getattr|hasattr|inspect\.signature")
    hits = [f"{p.relative_to(ROOT)}:{i}" for p in ROOT.rglob("*.py")
            if p.relative_to(ROOT).parts[0] not in ("cli", "io")
            for i, line in enumerate(p.read_text().splitlines(), 1) if probe.search(line)]
    assert len(hits) <= 15, hits
