"""A run folder written by release 0.1 (before the layout of issue 33) still loads and predicts the same
fields: state dicts and class names only, no module paths (tests/data/run_0_1: heat_1d, n = 16,
SIP, 5 steps, the prior fit's correction kept; predictions of 0.1 stored beside it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pdeinv.cli import main

RUN = Path(__file__).parent / "data" / "run_0_1"


def test_a_run_of_release_0_1_predicts_what_it_predicted_then(tmp_path):
    out = tmp_path / "p.npz"
    assert main(["predict", str(RUN), "--data", str(RUN / "obs.npz"), "--out", str(out)]) == 0
    now, then = np.load(out)["x"], np.load(RUN / "pred_0_1.npz")["x"]
    assert np.abs(now - then).max() <= 1e-6 * np.abs(then).max()
