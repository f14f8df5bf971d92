"""Compiled backends (dense, truncated SVD): exact to tolerance against the time stepping they replace."""

import numpy as np
import pytest
import torch
from exact import dot_test, load

import pdeinv
from pdeinv.inverse import FixedAlpha, SpectralTikhonov, TikhonovCG
from pdeinv.physics.backends import compiled

SCENES = {
    "wave_2d": dict(n=6, steps=20),
    "wave_sensors_2d": dict(n=6, steps=12, record_every=3, sensors=8),
    "heat_sensors_2d": dict(n=6, steps=10, record_every=2, sensors=5),
    "advection_diffusion_2d": dict(n=6, steps=10, speed=2.0),
    "heat_2d": dict(n=6, steps=10),
}
CASES = [(name, kind) for name in SCENES for kind in ("dense", "svd")]


def _pair(name, kind):
    kw = SCENES[name]
    return load(name, backend=kind, **kw).operator, load(name, backend="steps", **kw).operator


@pytest.mark.parametrize("name, kind", CASES)
def test_compiled_agrees_with_stepping_and_is_its_own_exact_transpose(name, kind):
    op, ref = _pair(name, kind)
    assert op.backend.name == kind
    rng = np.random.default_rng(0)
    X, R = rng.standard_normal((4, op.n_in)), rng.standard_normal((4, op.n_out))
    for a, b in ((op.forward(X), ref.forward(X)), (op.adjoint(R), ref.adjoint(R))):
        assert np.linalg.norm(a - b) <= 1e-10 * np.linalg.norm(b)
    assert dot_test(op) <= 1e-12
    np.testing.assert_allclose(op.forward(X[1]), op.forward(X)[1], rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("kind", ["dense", "svd"])
def test_compiled_gradcheck(kind):
    op = load("wave_sensors_2d", backend=kind, n=3, steps=4, record_every=2, sensors=3).operator
    x = torch.randn(2, op.n_in, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: pdeinv.apply(op, t), (x,))


def test_svd_truncates_a_smoothing_operator_and_keeps_its_tolerance():
    op = load("heat_2d", n=10, kappa=0.1, backend="svd").operator
    assert op.backend.k < op.n_in / 2  # heat smooths: most singular values are below rtol·s_max
    assert op.backend.g.min() >= compiled.SVD_RTOL * op.backend.g.max()


def test_svd_filter_inverse_equals_the_cg_solve_with_the_same_alpha():
    p = load("wave_sensors_2d", backend="svd", **SCENES["wave_sensors_2d"])
    assert isinstance(p.inverse_simulator, SpectralTikhonov)
    x, y = p.sample(3, seed=0)
    x0 = np.zeros_like(x)
    assert np.allclose(p.inverse(p.operator.forward(x0), x0), x0)  # exact at y = P x0
    alpha = 1e-3 * np.max(p.operator.modes.g) ** 2
    fast = SpectralTikhonov(p.operator, FixedAlpha(alpha))(y, x0)
    slow = TikhonovCG(p.operator, p.disc.M, FixedAlpha(alpha), M_out=None, rtol=1e-12)(y, x0)
    assert np.linalg.norm(fast - slow) <= 1e-6 * np.linalg.norm(slow)


def test_auto_plans_by_the_cost_of_a_run():
    assert load("wave_2d", n=8).operator.choice.startswith("auto: dense")
    assert load("wave_sensors_2d", **SCENES["wave_sensors_2d"]).operator.choice.startswith("auto: svd")
    kind, why = compiled.plan(1e3, 100, 100, reversible=True)  # cheap stepping, cheap inverse: keep it
    assert kind == "steps" and "dense≈" in why


def test_the_plan_counts_the_steps_the_run_will_take():
    """A 3-step run does not pay for a dense build; a long run does (wave_2d, 961 unknowns)."""
    with compiled.expecting(steps=3):
        short = load("wave_2d", n=30).operator
    with compiled.expecting(steps=2000, batch=64):
        long = load("wave_2d", n=30).operator
    assert short.choice.startswith("auto: steps") and "3 steps" in short.choice
    assert long.choice.startswith("auto: dense") and "2000 steps × 64 columns" in long.choice
    assert compiled.EXPECT["steps"] == 1000  # restored after the block
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match=f"steps={bad!r} is not allowed"):
            with compiled.expecting(steps=bad):
                pass


def test_a_cached_build_costs_nothing_in_the_plan(tmp_path, monkeypatch):
    """Stepping wins a 3-step run of wave_2d only while the dense matrix is not in the cache."""
    monkeypatch.setenv("PDEINV_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("PDEINV_NO_CACHE", raising=False)
    with compiled.expecting(steps=3):
        cold = load("wave_2d", n=30).operator
        assert cold.choice.startswith("auto: steps")
        load("wave_2d", n=30, backend="dense")  # fills the cache
        warm = load("wave_2d", n=30).operator
    assert warm.choice.startswith("auto: dense") and "(cached)" in warm.choice


def test_budget_refuses_an_explicit_choice_and_auto_falls_back(monkeypatch):
    monkeypatch.setenv("PDEINV_DENSE_BUDGET_GB", "1e-6")
    with pytest.raises(ValueError, match=r"backend='dense' needs about .* GB .* budget is 1e-06 GB"):
        load("wave_2d", n=8, backend="dense")
    op = load("wave_2d", n=8).operator
    assert op.backend is None and "over budget" in op.choice
    monkeypatch.setenv("PDEINV_DENSE_BUDGET_GB", "0")
    with pytest.raises(ValueError, match="PDEINV_DENSE_BUDGET_GB='0' is not allowed"):
        load("wave_2d", n=8)


def test_svd_tolerance_outside_zero_one_is_refused():
    with pytest.raises(ValueError, match="rtol=1.5 is not allowed"):
        compiled.SVD(np.eye(3), rtol=1.5)


@pytest.mark.parametrize("name, kw", [("heat_2d", dict(n=8, kappa=0.05)),
                                      ("heat_sensors_2d", dict(n=6, steps=10, record_every=2, sensors=9,
                                                               backend="svd"))])
def test_hig_on_compressed_rows_takes_the_same_step(name, kw):
    """``J = (I ⊗ Q) J_c``: the step from r rows per sample equals the one from all m rows."""
    from pdeinv.methods import HIG
    from pdeinv.methods.hig.rule import compress

    p = load(name, **kw)
    small, Q = compress(p.operator)
    assert Q is not None and small.n_out < p.operator.n_out
    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(p.operator.n_out, 6), torch.nn.Tanh(),
                                torch.nn.Linear(6, p.operator.n_in)).double()
    y = torch.as_tensor(p.sample(3, seed=0)[1])
    rule = HIG(route="svd")
    state = rule.init(p, model)
    full = state._replace(context=(p.operator, p.operator, None, set(), None))
    a, b = rule.update(state, model, y), rule.update(full, model, y)
    for da, db in zip(a.direction, b.direction, strict=True):
        assert torch.allclose(da, db, rtol=1e-6, atol=1e-9 * db.abs().max())
    assert a.info["rank"] == b.info["rank"]


def test_bench_has_a_line_per_backend():
    from pdeinv.bench import backends

    res = backends.lines(load("wave_sensors_2d", **SCENES["wave_sensors_2d"]), repeats=1)
    assert set(res["lines"]) == {"steps", "dense", "svd"}
    for line in res["lines"].values():
        assert line["outcome"] == "ok" and line["agreement"] <= 1e-10 and line["apply_s"] > 0
    assert res["lines"]["dense"]["memory_mb"] > 0 and res["lines"]["steps"]["memory_mb"] == 0
    heat = backends.lines(load("heat_2d", n=6, kappa=0.1), repeats=1)["lines"]
    assert "modal" in heat and heat["modal"]["rank"] < 25


def test_compiled_arrays_come_from_the_disk_cache_the_second_time(monkeypatch):
    calls = []
    real = compiled.matrix
    monkeypatch.setattr(compiled, "matrix", lambda *a, **k: calls.append(1) or real(*a, **k))
    kw = dict(n=5, steps=7, record_every=7, sensors=4, backend="svd")
    first = load("wave_sensors_2d", **kw).operator
    second = load("wave_sensors_2d", **kw).operator
    assert len(calls) == 1  # the second scene stepped nothing
    np.testing.assert_array_equal(first.backend.g, second.backend.g)
    load("wave_sensors_2d", **{**kw, "steps": 14, "record_every": 7})  # another map: a miss
    assert len(calls) == 2


def test_dense_wave_gets_the_spectral_filter_and_stepping_keeps_time_reversal(monkeypatch):
    """The default local inverse of a dense-compiled wave is the Tikhonov filter in the SVD of its
    ``P`` (exact at ``y = P x0``, and the exact inverse for noise-free data: P is well conditioned);
    a time-stepping wave keeps time reversal."""
    from pdeinv.inverse import SpectralTikhonov, TimeReversal

    p = load("wave_2d", n=8)
    inv = p.inverse_simulator
    assert isinstance(inv, SpectralTikhonov)
    x, y = p.sample(4, seed=0)
    x0 = np.random.default_rng(1).standard_normal(x.shape)
    assert np.allclose(inv(p.operator.forward(x0), x0), x0, atol=1e-12)
    assert np.linalg.norm(inv(y, x0) - x) <= 1e-6 * np.linalg.norm(x)
    stepping = load("wave_2d", n=8, backend="steps")
    assert isinstance(stepping.inverse_simulator, TimeReversal)