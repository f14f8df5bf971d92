"""The API reference builds from the docstrings (pdoc, ``make docs``) and holds the entry points."""

from __future__ import annotations

import pytest

pytest.importorskip("pdoc")


def test_the_api_reference_builds_with_the_entry_points(tmp_path):
    from pdeinv.util.apidocs import build

    pages = {p.relative_to(tmp_path).as_posix() for p in build(tmp_path)}
    for page in ("pdeinv.html", "pdeinv/training/trainer.html", "pdeinv/methods/sip.html",
                 "pdeinv/physics/propagator.html", "pdeinv/problem/definition.html"):
        assert page in pages, sorted(pages)[:20]
    trainer = (tmp_path / "pdeinv/training/trainer.html").read_text()
    assert "def train" in trainer or "train(" in trainer
    assert "Trainer" in trainer
