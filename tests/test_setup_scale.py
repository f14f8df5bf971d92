"""Set-up at scale (issue 35): samples drawn in batches equal the per-sample definition, set-up phases
are reported in metrics.json."""

import json

import numpy as np
import pytest

import pdeinv
from pdeinv.problem.sampling import gaussian_bumps


def _bumps_by_definition(points, n, rng, bumps=3, width=(0.05, 0.15)):
    """The bumps prior written as its docstring states it, one sample and one bump at a time."""
    lo, hi = points.min(axis=1), points.max(axis=1)
    span = hi - lo
    diam = float(np.linalg.norm(span))
    a = rng.uniform(-1.0, 1.0, size=(n, bumps))
    c = lo + span * rng.uniform(0.1, 0.9, size=(n, bumps, points.shape[0]))
    s = diam * rng.uniform(*width, size=(n, bumps))
    out = np.zeros((n, points.shape[1]))
    for i in range(n):
        for j in range(bumps):
            out[i] += a[i, j] * np.exp(-((points.T - c[i, j]) ** 2).sum(1) / (2 * s[i, j] ** 2))
    return out


@pytest.mark.parametrize("dim", [2, 3])
def test_chunked_bumps_equal_the_definition_to_rounding(dim):
    points = np.random.default_rng(0).random((dim, 500))
    ref = _bumps_by_definition(points, 70, np.random.default_rng(5))
    for chunk in (1, 16, 64, 1000):
        got = gaussian_bumps(points, 70, np.random.default_rng(5), chunk=chunk)
        assert np.abs(got - ref).max() <= 1e-14 * np.abs(ref).max()


@pytest.mark.parametrize("backend", ["steps", "modal"])
def test_batched_samples_equal_per_sample_forward_runs(backend):
    """``problem.sample(n)``: one batched forward (one multi-RHS solve per time step) gives each sample's
    own run to rounding."""
    p = pdeinv.load_problem("heat_2d", n=12, backend=backend, steps=20)
    x, y = p.sample(9, seed=3)
    one = np.vstack([p.operator.forward(x[i:i + 1]) for i in range(len(x))])
    assert np.abs(y - one).max() <= 1e-13 * np.abs(y).max()


def test_metrics_report_the_set_up_phases(tmp_path):
    from pdeinv.cli import main

    out = tmp_path / "run"
    code = main(["train", "--prior-fit", "0",
                 "heat_1d", "--set", "n=16", "--set", "steps=10", "--steps", "2", "--n-train", "32",
                 "--n-test", "8", "--export-samples", "0", "--out", str(out)])
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("setup", "setup_cpu"):  # wall and CPU seconds
        setup = metrics[key]
        for phase in ("build", "network", "samples", "fit", "rule", "total"):
            assert setup[phase] >= 0, setup
        parts = sum(v for k, v in setup.items() if k != "total")
        assert setup["total"] == pytest.approx(parts, abs=0.01)
