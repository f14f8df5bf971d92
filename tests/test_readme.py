"""The README's tutorial runs as written (in a temporary folder: it writes two files)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


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
