"""Local inverse simulators (pdeinv.inverse): exactness at y₀, filter bias, CG vs modal,
Morozov's discrepancy principle, wave time reversal, stability, bad input, cost."""

import time

import numpy as np
import pytest

import pdeinv
from pdeinv.inverse import (
    Discrepancy,
    ModalTikhonov,
    StateReversal,
    TikhonovCG,
    TimeReversal,
    default_inverse,
)

SMALL = {"heat_1d": {}, "heat_2d": {"n": 16, "backend": "steps"},
         "heat_2d_modal": {"n": 16, "backend": "modal"}, "wave_1d": {}, "wave_2d": {"n": 16}}


def load(key):
    return pdeinv.load_problem(key.replace("_modal", ""), **SMALL[key])


@pytest.mark.parametrize("key", list(SMALL))
def test_exact_at_y0(key):
    """inverse(P x₀, x₀) = x₀ to 1e-10 relative (the SIP requirement), for every problem's default."""
    p = load(key)
    x0, y0 = p.sample(6, seed=1)
    x = p.inverse(y0, x0)
    assert x.shape == x0.shape
    assert np.max(p.relative_error(x, x0)) <= 1e-10
    # single samples in, single samples out
    assert p.inverse(y0[0], x0[0]).shape == x0[0].shape


def well_observed_change(op, B, seed):
    """Δx = Σ d_k φ_k over the modes with amplification ≥ 1e-3·max g, and its coefficients."""
    g, Phi = op.backend.g, op.backend.Phi
    well = np.abs(g) >= 1e-3 * np.abs(g).max()
    d = np.random.default_rng(seed).standard_normal((B, well.sum()))
    return d @ Phi[:, well].T, d, well


@pytest.mark.parametrize("alpha", [1e-8, 1e-5])
def test_heat_modal_filter_bias(alpha):
    """Per mode the recovered change is g²/(g²+α) of the true one: error coefficient = α/(g²+α)·d_k."""
    p = load("heat_1d")
    op = p.operator
    x0, y0 = p.sample(5, seed=2)
    dx, d, well = well_observed_change(op, 5, seed=3)
    inv = ModalTikhonov(op, alpha)
    x = inv(y0 + op.forward(dx), x0)
    err = (x - x0 - dx) @ op.backend.MPhi  # modal coefficients of the error
    g2 = op.backend.g[well] ** 2
    predicted = -alpha / (g2 + alpha) * d
    assert np.allclose(err[:, well], predicted, rtol=1e-6, atol=1e-11)
    assert np.abs(err[:, ~well]).max() < 1e-11  # nothing leaks into other modes
    # and the data are fitted up to the same bias, pushed forward
    res = p.disc.norm(op.forward(x) - y0 - op.forward(dx))
    bound = np.sqrt(((op.backend.g[well] * alpha / (g2 + alpha) * d) ** 2).sum(1))
    assert np.all(res <= bound * (1 + 1e-6) + 1e-12)


def test_heat_cg_agrees_with_modal():
    """Block PCG on the stepping operator = modal filter, to the CG tolerance (plus modal tol)."""
    pm, ps = load("heat_2d_modal"), load("heat_2d")
    x0, y0 = pm.sample(4, seed=4)
    dx, _, _ = well_observed_change(pm.operator, 4, seed=5)
    alpha = 1e-6
    xm = ModalTikhonov(pm.operator, alpha)(y0 + pm.operator.forward(dx), x0)
    cg = TikhonovCG(ps.operator, ps.operator.M, alpha, rtol=1e-10)
    xc = cg(ps.operator.forward(x0 + dx), x0)
    info = cg.last_info
    assert info["converged"] and np.all(info["residual"] <= 1e-10)
    assert np.max(pm.relative_error(xc - x0, xm - x0)) < 1e-8
    print(f"\nCG: iterations {info['iterations'].tolist()}, cost {info['forward_units']:.0f} "
          "forward-solve units")


def test_generic_fallback_for_any_operator():
    """A plain matrix operator gets a CG inverse from default_inverse.

    It is exact at y₀ and inverts when the problem is well posed."""
    A = np.random.default_rng(0).standard_normal((30, 20))
    op = pdeinv.physics.Matrix(A)
    inv = default_inverse(op)
    assert isinstance(inv, TikhonovCG)
    x0 = np.random.default_rng(1).standard_normal((3, 20))
    x = np.random.default_rng(2).standard_normal((3, 20))
    assert np.allclose(inv(op.forward(x0), x0), x0, atol=1e-12)
    inv = TikhonovCG(op, None, alpha=1e-12)
    assert np.allclose(inv(op.forward(x), x0), x, atol=1e-8)  # full column rank: α→0 is the inverse


def test_discrepancy_principle():
    """Morozov on noisy heat_1d: residual ≈ τ·noise (within 10%).

    The x-error is within 1.5× that of the best α on a log grid."""
    noise = 0.01
    p = pdeinv.load_problem("heat_1d", n=128, noise=noise)
    op = p.operator
    x, y = p.sample(32, seed=3)
    x0 = np.zeros_like(x)
    rule = Discrepancy(noise)
    inv = ModalTikhonov(op, rule)
    xa = inv(y, x0)
    actual = p.disc.norm(y - op.forward(x))
    res = p.disc.norm(op.forward(xa) - y)
    assert abs(np.mean(res / (rule.tau * actual)) - 1) < 0.1
    grid = np.logspace(-14, 0, 57) * (op.backend.g**2).max()
    best = min(np.mean(p.relative_error(ModalTikhonov(op, a)(y, x0), x)) for a in grid)
    err = np.mean(p.relative_error(xa, x))
    assert err <= 1.5 * best, (err, best)
    # the CG backend meets the same principle on the full residual (the spectral one on the kept modes)
    cg = TikhonovCG(op, op.M, rule, rtol=1e-12)
    res = p.disc.norm(op.forward(cg(y, x0)) - y)
    assert abs(np.sqrt((res**2).sum() / (actual**2).sum()) / rule.tau - 1) < 0.1
    assert np.ptp(cg.last_info["alpha"]) == 0  # pooled: one α for the batch
    each = ModalTikhonov(op, Discrepancy(noise, pooled=False))
    each(y, x0)
    assert np.ptp(np.log(each.last_info["alpha"])) > 0.1  # per sample: α differs between samples


def test_wave_full_state_reversal_exact():
    """Observing (u_T, v_T), reversal recovers u₀ to rounding."""
    p = load("wave_2d")
    x, _ = p.sample(4, seed=6)
    UT, VT = p.operator.final_state(x)
    u0 = StateReversal(p.operator)(np.hstack([UT, VT]))
    assert np.max(p.relative_error(u0, x)) <= 1e-10


def test_wave_time_reversal_first_order():
    """For y = P(x₀ + εd): e(ε) = ‖inverse(y, x₀) − (x₀ + εd)‖_M is exactly linear in ε.

    By linearity the error is −ε·(R_v v_T(d))_u — the part of u₀ the unobserved
    velocity change would have carried back — so e(ε) ∝ ε¹: fitted slope of
    log e vs log ε is 1 (a slope 0 would mean the inverse is not exact at y₀),
    and e(ε)/ε equals the predicted constant.
    """
    p = load("wave_1d")
    op = p.operator
    x0, _ = p.sample(1, seed=7)
    d, _ = p.sample(1, seed=8)
    inv = TimeReversal(op)
    eps = np.logspace(-6, 0, 7)
    errs = np.array([p.disc.norm(inv(op.forward(x0 + e * d), x0) - (x0 + e * d))[0] for e in eps])
    slope = np.polyfit(np.log(eps), np.log(errs), 1)[0]
    assert abs(slope - 1) < 0.02
    predicted = p.disc.norm(op.reverse(np.zeros_like(d), op.final_state(d)[1])[0])[0]
    assert np.allclose(errs / eps, predicted, rtol=1e-6)
    assert predicted > 1e-3 * p.disc.norm(d)[0]  # the velocity term is real, not rounding


@pytest.mark.parametrize("kappa", [1e-3, 1e-2, 1e-1, 1.0])
def test_stability_small_alpha_and_kappa_range(kappa):
    """No NaN/Inf for α down to 1e-12 and κT over four decades; still exact at y₀."""
    p = pdeinv.load_problem("heat_1d", kappa=kappa, backend="modal")
    x0, y0 = p.sample(4, seed=9)
    x, y = p.sample(4, seed=10)
    for alpha in [1e-12, 1e-9, 1e-6]:
        for inv in (ModalTikhonov(p.operator, alpha), TikhonovCG(p.operator, p.operator.M, alpha)):
            out = inv(y, x0)
            assert np.isfinite(out).all()
            assert np.max(p.relative_error(inv(y0, x0), x0)) <= 1e-10


def test_bad_input_refused():
    p = load("heat_1d")
    op = p.operator
    x0, y0 = p.sample(2)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="alpha"):
            ModalTikhonov(op, bad)
        with pytest.raises(ValueError, match="alpha"):
            TikhonovCG(op, op.M, bad)
    with pytest.raises(ValueError, match="noise"):
        Discrepancy(0.0)
    inv = p.inverse_simulator
    y_nan = y0.copy()
    y_nan[0, 3] = np.nan
    with pytest.raises(ValueError, match="y contains NaN"):
        inv(y_nan, x0)
    with pytest.raises(ValueError, match="x0 has shape"):
        inv(y0, x0[:, :-1])
    with pytest.raises(ValueError, match="samples"):
        inv(y0, x0[:1])
    with pytest.raises(ValueError, match="modal backend"):
        ModalTikhonov(load("heat_2d").operator, 1e-6)
    with pytest.raises(ValueError, match="time-reversible operator"):
        TimeReversal(op)


def test_cost_report():
    """The default inverses' cost (printed, not asserted: wall time on a shared machine), and what the
    timed calls must have computed (asserted).

    Modal heat_2d (961 unknowns): exact at y₀. CG on stepping heat_2d (n=16): converged; its Δx
    solves the normal equations ``(PᵀMP + αM)Δx = PᵀM(y − y₀)`` of the module docstring; its call
    counts follow the documented cost: 1 forward (y₀) + 1 adjoint (right-hand side) + per iteration
    one forward and one adjoint on the columns still running, so ``forward_units = 2 + 2·mean(it)``
    and ``calls = 1 + max(it)`` each; and CG needs far fewer iterations than unknowns.
    """
    p = pdeinv.load_problem("heat_2d")  # 961 unknowns, modal backend
    op = p.operator
    x0, y0 = p.sample(64, seed=11)
    inv = p.inverse_simulator
    assert isinstance(inv, ModalTikhonov)
    assert np.max(p.relative_error(inv(y0, x0), x0)) <= 1e-10

    def best(f, reps=20):
        ts = []
        for _ in range(reps):
            t = time.perf_counter()
            f()
            ts.append(time.perf_counter() - t)
        return min(ts)

    t_fwd, t_inv = best(lambda: op.forward(x0)), best(lambda: inv(y0, x0))
    ps = load("heat_2d")
    xs, ys = ps.sample(16, seed=12)
    cg = ps.inverse_simulator
    assert isinstance(cg, TikhonovCG)
    t_sfwd = best(lambda: ps.operator.forward(xs), 3)
    t_cg = best(lambda: cg(ys, np.zeros_like(xs)), 1)
    info = cg.last_info
    print(f"\nmodal heat_2d B=64: forward {1e3 * t_fwd:.2f} ms, inverse {1e3 * t_inv:.2f} ms "
          f"({t_inv / t_fwd:.2f}x)")
    print(f"CG heat_2d n=16 B=16 (α={info['alpha'][0]:.2g}): {info['iterations'].max()} iterations, "
          f"{info['forward_units']:.0f} forward-solve units counted, {t_cg / t_sfwd:.0f}x one forward "
          "in wall time")
    assert info["converged"] and np.all(info["residual"] <= cg.rtol)
    it = info["iterations"]
    assert info["calls"] == {"forward": 1 + it.max(), "adjoint": 1 + it.max()}
    assert np.isclose(info["forward_units"], 2 + 2 * it.mean())
    assert it.max() < ps.N / 3
    sop, M = ps.operator, ps.operator.M
    dx = cg(ys, np.zeros_like(xs))
    lhs = sop.adjoint((M @ sop.forward(dx).T).T) + info["alpha"][:, None] * (M @ dx.T).T
    rhs = sop.adjoint((M @ ys.T).T)
    assert np.max(np.linalg.norm(lhs - rhs, axis=1) / np.linalg.norm(rhs, axis=1)) < 1e-8  # 8e-11 seen
