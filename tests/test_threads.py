"""``--threads`` bounds every thread pool (:mod:`pdeinv.util.threads`): torch's and the BLAS/OpenMP pools."""

import pytest
import torch
from threadpoolctl import threadpool_limits

from pdeinv.cli import main
from pdeinv.training.trainer import Trainer
from pdeinv.util import threads


@pytest.fixture(autouse=True)
def _two_threads():
    """The suite runs on one thread (conftest): two here, so that a limit to one is seen to act."""
    with threadpool_limits(limits=2, user_api="blas"):
        yield


def _counts():
    return {p["filepath"]: p["num_threads"] for p in threads.info()}


def test_limit_bounds_every_blas_pool_and_restore_undoes_it():
    before = _counts()
    assert 2 in set(before.values())
    assert any("blas" in p["user_api"] for p in threads.info())  # numpy's and scipy's BLAS are seen
    threads.limit(1)
    try:
        assert set(_counts().values()) == {1} and torch.get_num_threads() == 1
    finally:
        threads.restore()
    assert _counts() == before


def test_cli_threads_1_holds_during_training_and_is_undone_after(tmp_path, monkeypatch):
    seen, fit = [], Trainer.fit
    before = _counts()

    def spy(self):
        seen.append(_counts())
        return fit(self)

    monkeypatch.setattr(Trainer, "fit", spy)
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--set", "n=16", "--set", "steps=10", "--n-train", "16", "--n-test",
                 "8", "--steps", "2", "--threads", "1", "--export-samples", "0", "--out", str(tmp_path)]) == 0
    assert seen and set(seen[0].values()) == {1}
    assert _counts() == before
