"""The README's tutorial and every python block of the docs pages run as written; their relative links
resolve, and docs/train.md shows what ``--explain`` prints.

Each runs in a temporary folder (they write files). Blocks not meant to run are fenced ```bash,
```sh or ```text; the ```bash lines of the sections with a dedicated test below run through the CLI.
"""

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.glob("*.md"))
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", flags=re.S | re.M)
LANGUAGES = {"python", "bash", "sh", "text"}
#: sections whose blocks a dedicated test runs (with their `pdeinv` lines): page -> headings
DEDICATED = {"own-data.md": ["# Your own observations"], "problems.md": ["## Your own problem"]}


def _section(page: Path, heading: str) -> str:
    """The text of ``page`` after the line ``heading`` up to the next heading of level 1 to 3.

    Lines inside fenced blocks (a python comment starts with ``# `` too) are not headings.
    """
    lines, found, fenced = [], False, False
    for line in page.read_text().splitlines(keepends=True):
        fenced ^= line.startswith("```")
        is_heading = not fenced and re.match(r"#{1,3} ", line) is not None
        if found and is_heading:
            break
        if found:
            lines.append(line)
        found = found or (is_heading and line.rstrip("\n") == heading)
    assert found, f"{page.name} has no heading {heading!r}"
    return "".join(lines)


def _blocks(text: str) -> list[tuple[str, str]]:
    return FENCE.findall(text)


#: pages whose relative links must resolve: the README, the guides, the lab notes
LINKED = [README, *PAGES, *sorted((ROOT / "benchmarks" / "notes").glob("*.md"))]


def _anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text())
    return {_anchor(h) for h in re.findall(r"^#{1,6} (.+)$", text, flags=re.M)}


@pytest.mark.parametrize("page", LINKED, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    """Every relative link of the README, the guides and the lab notes names a file that exists, and
    an anchor into a markdown page names one of its headings (pages move: docs/ → benchmarks/notes/)."""
    text = FENCE.sub("", page.read_text())
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        where = (page.parent / path).resolve() if path else page
        assert where.exists(), f"{page.name}: the link {target!r} names no file"
        if anchor and where.suffix == ".md":
            assert anchor in _anchors(where), f"{page.name}: the link {target!r} names no heading"


def test_train_page_shows_what_explain_prints(capsys):
    """docs/train.md pastes the output of its `pdeinv train ... --explain` line: it is the current one
    (the memory line's estimates aside)."""
    import shlex

    from pdeinv.cli import main

    block = next(code for lang, code in _blocks((DOCS / "train.md").read_text())
                 if lang == "text" and code.startswith("$ pdeinv train"))
    command, *shown = block.strip().splitlines()
    argv = shlex.split(command.removeprefix("$ "))
    capsys.readouterr()
    assert main([*argv[1:], "--threads", "1"]) == 0
    printed = capsys.readouterr().out.strip().splitlines()
    strip = lambda lines: [line for line in lines if not line.startswith("memory")]  # noqa: E731
    assert strip(printed) == strip(shown)
    assert [line.split()[0] for line in printed] == [line.split()[0] for line in shown]


def test_every_block_names_its_language():
    """An unnamed fence would be neither run nor marked as not meant to run."""
    for page in [README, *PAGES]:
        for lang, _ in _blocks(page.read_text()):
            assert lang in LANGUAGES, f"{page.name}: a ```{lang} block (use one of {sorted(LANGUAGES)})"


def test_readme_has_only_the_tutorial_block():
    """The tutorial test runs the README's first python block: more would go unrun."""
    assert [lang for lang, _ in _blocks(README.read_text())].count("python") == 1
    for name in DEDICATED:
        assert (DOCS / name).is_file(), f"docs/{name} is gone: update DEDICATED"


def test_readme_tutorial_runs(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "README has no python block"
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(blocks[0], str(README), "exec"), namespace)
    assert namespace["result"].metrics["x_err"] < 0.8
    assert (tmp_path / "prediction.png").stat().st_size > 1000
    assert (tmp_path / "prediction.vtu").is_file()
    capsys.readouterr()


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_docs_page_python_blocks_run(page, tmp_path, monkeypatch, capsys):
    """Every python block of a docs page outside the dedicated sections, in order, one namespace."""
    text = page.read_text()
    for heading in DEDICATED.get(page.name, []):
        text = text.replace(_section(page, heading), "")
    monkeypatch.chdir(tmp_path)
    namespace = {}
    for lang, code in _blocks(text):
        if lang == "python":
            exec(compile(code, str(page), "exec"), namespace)
    capsys.readouterr()


def test_own_observations_section_runs(tmp_path, monkeypatch, capsys):
    """docs/own-data.md: its python blocks, and its `pdeinv` lines through the CLI."""
    import shlex

    import numpy as np

    from pdeinv.cli import main

    page = DOCS / "own-data.md"
    blocks = _blocks(_section(page, "# Your own observations"))
    assert [kind for kind, _ in blocks] == ["python", "bash", "python"]
    monkeypatch.chdir(tmp_path)
    namespace = {}
    for kind, code in blocks:
        if kind == "python":
            exec(compile(code, str(page), "exec"), namespace)
            continue
        for line in code.strip().splitlines():
            argv = shlex.split(line)
            assert argv[0] == "pdeinv"
            assert main([*argv[1:], "--threads", "1"]) == 0, capsys.readouterr().err
    metrics = json.loads((tmp_path / "runs/own/metrics.json").read_text())
    assert metrics["data"]["rows"] == {"train": [0, 320], "calibration": [320, 400], "stop": [400, 400],
                                       "test": [400, 500]}
    assert metrics["x_err"] < 0.5  # measured 0.237 on 400 training rows
    xhat = np.load(tmp_path / "pred.npz")["x"]
    assert xhat.shape == (100, namespace["problem"].N)
    assert namespace["problem"].relative_error(xhat, namespace["x"][500:]).mean() < 0.5
    assert (tmp_path / "pred.vtu").is_file()
    capsys.readouterr()


def test_own_problem_section_runs(tmp_path, monkeypatch, capsys):
    """docs/problems.md "Your own problem": its module, saved where it says, trains by name."""
    import shlex

    from pdeinv.cli import main

    blocks = _blocks(_section(DOCS / "problems.md", "## Your own problem"))
    assert [kind for kind, _ in blocks] == ["python", "bash"]
    code = blocks[0][1]
    where = code.splitlines()[0].removeprefix("# ").strip()
    (tmp_path / where).parent.mkdir(parents=True)
    (tmp_path / where).write_text(code)
    monkeypatch.chdir(tmp_path)
    for line in blocks[1][1].strip().splitlines():
        argv = shlex.split(line)
        assert main([*argv[1:], "--steps", "3", "--n-train", "64", "--n-test", "16", "--threads", "1",
                     "--export-samples", "0"]) == 0, capsys.readouterr().err
    metrics = json.loads((tmp_path / "runs/rod/metrics.json").read_text())
    assert metrics["problem"] == "my_rod" and metrics["x_err"] < 0.5
    capsys.readouterr()
