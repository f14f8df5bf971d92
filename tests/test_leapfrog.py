"""Explicit leapfrog wave scheme: exact adjoint, second-order convergence, CFL refusal."""

import numpy as np
import pytest
import torch
from exact import dot_test, eigenvalue, fitted_rate, l2_error, load, mode

import pdeinv
from pdeinv.cli import main


@pytest.mark.parametrize("name, kw", [("wave_1d", dict(n=32, steps=64)), ("wave_2d", dict(n=8, steps=20))])
def test_dot_product_and_gradcheck(name, kw):
    op = load(name, scheme="leapfrog", **kw).operator
    assert isinstance(op, pdeinv.physics.Leapfrog)
    assert dot_test(op) < 1e-12
    x = torch.randn(2, op.n_in, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: pdeinv.apply(op, t), (x,))


def test_batched_equals_per_sample():
    op = load("wave_2d", n=6, steps=12, scheme="leapfrog").operator
    X = np.random.default_rng(0).standard_normal((3, op.n_in))
    np.testing.assert_allclose(op.forward(X), np.stack([op.forward(x) for x in X]), rtol=1e-13)


def test_second_order_at_fixed_cfl_number():
    """u₀ = sin(πx): u(T) = cos(π T) u₀. Lumped P1 + leapfrog at c·dt/h = 0.5: rate 2 in h."""
    hs, errs = [], []
    for n in (16, 32, 64, 128):
        p = load("wave_1d", n=n, steps=2 * n, T=1.0, scheme="leapfrog")
        x = mode(p.points)[None]
        errs.append(l2_error(p.disc, p.operator.forward(x), np.cos(np.sqrt(eigenvalue(1)) * 1.0)))
        hs.append(1.0 / n)
    assert abs(fitted_rate(hs, errs) - 2.0) < 0.15, errs


def test_dt_above_the_cfl_limit_is_refused_with_the_limit():
    # 1-D lumped P1, n = 64: λ_max = 4/h² · sin²(63π/128) just below 4/h², so dt_max is just above
    # h = 1/64 and T = 0.5 needs 32 steps
    limit = r"dt = T/steps = 0.01613.*limit 2/\(c·√λ_max\) = 0.01563.*steps >= 32"
    with pytest.raises(ValueError, match=limit):
        load("wave_1d", scheme="leapfrog", steps=31, T=0.5)
    op = load("wave_1d", scheme="leapfrog", steps=32, T=0.5).operator
    assert 1 / 64 == op.dt < op.dt_max < 1.001 / 64
    with pytest.raises(ValueError, match="element='P2'.*lumped mass"):
        load("wave_2d", n=4, element="P2", scheme="leapfrog")
    with pytest.raises(ValueError, match="scheme='rk4' is not allowed.*'newmark', 'leapfrog'"):
        load("wave_1d", scheme="rk4")


def test_cli_refuses_dt_above_cfl_in_one_line(tmp_path, capsys):
    argv = ["train", "--prior-fit", "0",
            "wave_1d", "--set", "scheme=leapfrog", "--set", "steps=10", "--set", "T=0.5",
            "--out", str(tmp_path / "r")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "stability limit" in err and "steps >= 32" in err
    assert not (tmp_path / "r" / "metrics.json").exists()


def test_stress_sweep_reports_leapfrog_below_ok_and_above_refused():
    from pdeinv.bench.cases import cases
    from pdeinv.bench.stress import run

    rows = run([c for c in cases("wave_2d", {"n": 8, "steps": 10}, quick=True) if c.sweep == "explicit"])
    by = {r["value"]: r for r in rows}
    assert by["leapfrog_0.9x_cfl"]["outcome"] == "ok" and by["leapfrog_0.9x_cfl"]["growth"] <= 1.0
    assert by["leapfrog_1.1x_cfl"]["outcome"] == "refused"
    assert "stability limit" in by["leapfrog_1.1x_cfl"]["message"]
