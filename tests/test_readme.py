"""The README's tutorial runs as written (in a temporary folder: it writes two files)."""

import json
import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _section(heading: str) -> str:
    """The README's text from ``heading`` to the next heading of level 2 or 3."""
    return re.split(r"\n#{2,3} ", README.read_text().split(heading, 1)[1], maxsplit=1)[0]


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


def test_readme_own_observations_section_runs(tmp_path, monkeypatch, capsys):
    """The "Your own observations" section: its python blocks, and its `pdeinv` lines through the CLI."""
    import shlex

    import numpy as np

    from pdeinv.cli import main

    section = _section("### Your own observations")
    blocks = re.findall(r"```(python|bash)\n(.*?)```", section, flags=re.S)
    assert [kind for kind, _ in blocks] == ["python", "bash", "python"]
    monkeypatch.chdir(tmp_path)
    namespace = {}
    for kind, code in blocks:
        if kind == "python":
            exec(compile(code, str(README), "exec"), namespace)
            continue
        for line in code.strip().splitlines():
            argv = shlex.split(line)
            assert argv[0] == "pdeinv"
            assert main([*argv[1:], "--threads", "1"]) == 0, capsys.readouterr().err
    metrics = json.loads((tmp_path / "runs/own/metrics.json").read_text())
    assert metrics["data"]["rows"] == {"train": [0, 400], "stop": [400, 400], "test": [400, 500]}
    assert metrics["x_err"] < 0.5  # measured 0.237
    xhat = np.load(tmp_path / "pred.npz")["x"]
    assert xhat.shape == (100, namespace["problem"].N)
    assert namespace["problem"].relative_error(xhat, namespace["x"][500:]).mean() < 0.5
    assert (tmp_path / "pred.vtu").is_file()
    capsys.readouterr()


def test_readme_own_problem_section_runs(tmp_path, monkeypatch, capsys):
    """The "Your own problem" section: its module, saved where it says, trains by name."""
    import shlex

    from pdeinv.cli import main

    section = _section("### Your own problem")
    blocks = re.findall(r"```(python|bash)\n(.*?)```", section, flags=re.S)
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
