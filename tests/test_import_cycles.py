"""The update rules and the trainer's modules import one way: no cycle among them (``methods/base.py``
and ``methods/guard.py`` imported each other until the guard became a leaf that ``base`` builds on)."""

from __future__ import annotations

import ast
from pathlib import Path

import pdeinv

ROOT = Path(pdeinv.__file__).parent
#: the modules whose imports must not form a cycle: the rules, the guard and what the trainer composes
SCOPE = ("pdeinv.methods", "pdeinv.training.trainer", "pdeinv.training.trainset",
         "pdeinv.training.evaluation", "pdeinv.training.checkpoint",
         "pdeinv.training.data", "pdeinv.training.stopping", "pdeinv.util.progress", "pdeinv.io.runs")


def imports() -> dict[str, set[str]]:
    """Module -> the package modules it imports anywhere in its source (function-level imports too)."""
    modules = {}
    for path in ROOT.rglob("*.py"):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                base = package.split(".")[:len(package.split(".")) - node.level + 1] if node.level else []
                target = ".".join([*base, *([node.module] if node.module else [])])
                deps |= {t for t in (target, *(f"{target}.{a.name}" for a in node.names)) if t in modules}
            elif isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name in modules}
        graph[name] = deps - {name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, found, counter = {}, {}, [], [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while not component or v not in component:
                component.add(stack.pop())
            if len(component) > 1:
                found.append(component)

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_the_rules_and_the_trainer_have_no_import_cycle():
    graph = imports()
    assert {"pdeinv.methods.base", "pdeinv.methods.guard"} <= set(graph)
    inside = [c for c in cycles(graph) if any(m.startswith(SCOPE) for m in c)]
    assert inside == [], inside


def test_the_finder_sees_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]
