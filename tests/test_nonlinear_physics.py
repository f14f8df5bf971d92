"""Nonlinear physics (issue 34): exact discrete adjoints of Allen–Cahn heat (Newton per step,
checkpointed) and sine-Gordon wave (Störmer–Verlet, reverse stepping), the torch bridge, and the
zero-strength limits against the linear scenes."""

import numpy as np
import pytest
import scipy.sparse as sp
import torch

import pdeinv
from pdeinv.fem.forms import discretize
from pdeinv.physics.nonlinear import is_linear, require_linear
from pdeinv.physics.reaction import NewtonFailed, ReactionHeat
from pdeinv.physics.sine_gordon import SineGordon
from pdeinv.problem.nonlinear_scenes import lumped_mass
from pdeinv.problem.sampling import gaussian_bumps


def _disc(n=32):
    return discretize(pdeinv.mesh.interval(n))


def _ops(n=32):
    d = _disc(n)
    return {
        "allen_cahn_be": ReactionHeat(d.M, d.K, kappa=0.01, T=1.0, steps=40, strength=5.0),
        "allen_cahn_cn": ReactionHeat(d.M, d.K, kappa=0.01, T=1.0, steps=40, strength=5.0, scheme="cn"),
        "sine_gordon": SineGordon(lumped_mass(d), d.K, c=1.0, T=1 / 3, strength=100.0),
    }


def _draw(op, b=4, seed=0, amp=2.0):
    d = _disc(op.n_in + 1)
    return amp * gaussian_bumps(d.points, b, np.random.default_rng(seed))


@pytest.mark.parametrize("name", ["allen_cahn_be", "allen_cahn_cn", "sine_gordon"])
def test_dot_product_of_jvp_and_vjp(name):
    """⟨P'(x)v, r⟩ = ⟨v, P'(x)ᵀr⟩ to 1e-12: vjp is the exact transpose of the discrete tangent."""
    op = _ops()[name]
    X = _draw(op)
    rng = np.random.default_rng(1)
    V, R = rng.standard_normal(X.shape), rng.standard_normal(X.shape)
    a = np.einsum("bi,bi->b", op.jvp(X, V), R)
    b = np.einsum("bi,bi->b", V, op.vjp(X, R))
    assert np.max(np.abs(a - b) / np.abs(a)) <= 1e-12


@pytest.mark.parametrize("name", ["allen_cahn_be", "allen_cahn_cn", "sine_gordon"])
def test_taylor_remainder_is_second_order(name):
    """‖P(x + hv) − P(x) − h P'(x)v‖ = O(h²): the fitted rate is at least 1.95."""
    op = _ops()[name]
    X = _draw(op, b=2)
    V = _draw(op, b=2, seed=5, amp=1.0)
    P0, J = op.forward(X), op.jvp(X, V)
    hs = 1e-3 * 0.5 ** np.arange(4)
    err = [np.linalg.norm(op.forward(X + h * V) - P0 - h * J) for h in hs]
    rate = np.polyfit(np.log(hs), np.log(err), 1)[0]
    assert rate >= 1.95, (rate, err)


@pytest.mark.parametrize("name", ["allen_cahn_be", "sine_gordon"])
def test_gradcheck_through_the_bridge(name):
    d = discretize(pdeinv.mesh.interval(8))
    op = (ReactionHeat(d.M, d.K, kappa=0.05, T=0.5, steps=8, strength=3.0) if name == "allen_cahn_be"
          else SineGordon(lumped_mass(d), d.K, T=0.2, strength=50.0))
    x = torch.tensor(_draw(op, b=2), dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: pdeinv.apply(op, t), (x,), eps=1e-6, atol=1e-8)
    # forward mode: torch.func.jvp is op.jvp
    v = torch.randn_like(x)
    _, tangent = torch.func.jvp(lambda t: pdeinv.apply(op, t), (x.detach(),), (v,))
    assert np.allclose(tangent.numpy(), op.jvp(x.detach().numpy(), v.numpy()), rtol=0, atol=1e-14)


def test_newton_converges_quadratically():
    """From the poor guess w₀ = u (no change), with a large dt·r: the Newton updates fall like
    δ_{k+1} ≈ C δ_k² until rounding (the log-ratio of consecutive updates approaches 2)."""
    d = _disc(32)
    op = ReactionHeat(d.M, d.K, kappa=0.01, T=1.0, steps=4, strength=3.0, solver="newton")  # dt·r = 0.75
    U = _draw(op, b=3).T
    history = []
    W = op.step(U, history=history, guess=U)
    h = np.array(history)
    assert len(h) <= 8, h
    again = []  # restarted at the answer, Newton moves it by rounding only: it had converged
    op.step(U, history=again, guess=W)
    assert again[0] <= 1e-14, again
    pairs = [(a, b) for a, b in zip(h[:-1], h[1:], strict=True) if a < 1e-2 and b > 1e-14]
    assert pairs, h
    assert all(np.log(b) / np.log(a) >= 1.8 for a, b in pairs), h
    # the default predictor needs two or three iterations at the scene's defaults
    op = ReactionHeat(d.M, d.K, kappa=0.01, T=1.0, steps=100, strength=1.0, solver="newton")
    op.forward(_draw(op, b=8))
    assert max(op.newton_iterations) <= 3


def test_newton_refuses_steps_where_the_step_is_not_unique():
    d = _disc(8)
    with pytest.raises(ValueError, match="steps >= 11"):
        ReactionHeat(d.M, d.K, T=1.0, steps=10, strength=10.0)
    op = ReactionHeat(d.M, d.K, T=1.0, steps=40, strength=10.0, max_newton=1, solver="newton")
    with pytest.raises(NewtonFailed, match="more steps"):
        op.step(_draw(op, b=1).T, guess=np.zeros((op.n_in, 1)))


def test_checkpointed_adjoint_equals_the_stored_trajectory():
    """Every-k checkpointing (k = ⌈√steps⌉, and a k that does not divide steps) gives the adjoint of
    the store-all run, holding O(√steps) fields."""
    d = _disc(32)
    X = _draw(ReactionHeat(d.M, d.K, steps=2), b=3)
    R = np.random.default_rng(2).standard_normal(X.shape)
    store = ReactionHeat(d.M, d.K, steps=64, strength=2.0, checkpoint_every=1)
    ref = store.vjp(X, R)
    assert store.peak_fields == 65  # the trajectory, stored
    for k in (None, 7):
        op = ReactionHeat(d.M, d.K, steps=64, strength=2.0, checkpoint_every=k)
        assert np.max(np.abs(op.vjp(X, R) - ref)) <= 1e-14 * np.max(np.abs(ref))
        assert op.peak_fields <= 2 * np.sqrt(64) + 2 + (k is not None)


def test_sine_gordon_reverse_recomputation_equals_the_stored_trajectory():
    op = _ops()["sine_gordon"]
    store = SineGordon(op.mass, op.K, c=op.c, T=op.t_end, steps=op.steps, strength=op.strength,
                       recompute="store")
    X = _draw(op, amp=3.0)
    R = np.random.default_rng(3).standard_normal(X.shape)
    ref = store.vjp(X, R)
    assert np.max(np.abs(op.vjp(X, R) - ref)) <= 1e-12 * np.max(np.abs(ref))
    # after a forward at bitwise the same X (the bridge) the sweep starts from that run's final state,
    # which is what it would march to: the same cotangent to the bit; at another X it marches
    op.forward(X)
    assert op._last is not None and np.array_equal(op._last[0], X)
    after = op.vjp(X, R)
    op.forward(X + 1.0)
    assert np.array_equal(after, op.vjp(X, R))
    # final_state from (X, 0) returns the kept run's state (time reversal after SIP's forward), as copies
    marched = SineGordon(op.mass, op.K, c=op.c, T=op.t_end, steps=op.steps, strength=op.strength)
    op.forward(X[:1])
    UT, VT = op.final_state(X[:1])
    assert all(np.array_equal(a, b) for a, b in zip((UT, VT), marched.final_state(X[:1]), strict=True))
    UT += 1.0
    assert np.array_equal(op.final_state(X[:1])[0], marched.final_state(X[:1])[0])


def test_sine_gordon_marches_blocks_of_columns_to_the_same_bits(monkeypatch):
    """Forward, jvp and vjp march blocks of columns that stay in cache (BLOCK_ENTRIES): each column's
    arithmetic is the same, so blocks of 3 give the whole batch's results to the bit."""
    from pdeinv.physics import sine_gordon

    op = _ops()["sine_gordon"]
    X, V = _draw(op, b=8, amp=3.0), np.random.default_rng(4).standard_normal((8, op.n_in))
    R = np.random.default_rng(5).standard_normal((8, op.n_out))
    whole = [op.forward(X), op.jvp(X, V), op.vjp(X + 0.0, R)]
    monkeypatch.setattr(sine_gordon, "BLOCK_ENTRIES", 3 * op.n_in)
    op._last = None
    blocks = [op.forward(X), op.jvp(X, V), op.vjp(X + 0.0, R)]
    assert all(np.array_equal(a, b) for a, b in zip(whole, blocks, strict=True))


def test_sine_gordon_reverse_stepping_returns_the_initial_state():
    p = pdeinv.load_problem("sine_gordon_1d")
    x, y = p.sample(8, seed=0)
    UT, VT = p.operator.final_state(x)
    assert np.array_equal(UT, y)
    U0, V0 = p.operator.reverse(UT, VT)
    assert np.max(np.abs(U0 - x)) <= 1e-13 * np.max(np.abs(x))
    assert np.max(np.abs(V0)) <= 1e-12 * np.max(np.abs(VT))
    # the local inverse (reverse stepping from (y, v_T(x₀))) keeps the contract P⁻¹(P x₀) = x₀
    assert np.max(np.abs(p.inverse(y, x) - x)) <= 1e-13 * np.max(np.abs(x))


def test_sine_gordon_refuses_a_step_above_the_stability_limit():
    d = _disc(32)
    with pytest.raises(ValueError, match="stability limit"):
        SineGordon(lumped_mass(d), d.K, T=1.0, steps=5, strength=10.0)


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def test_zero_strength_reproduces_the_linear_scenes():
    """strength=0: allen_cahn_1d is heat_1d's map, sine_gordon_1d (same steps) wave_1d's leapfrog."""
    ac, heat = pdeinv.load_problem("allen_cahn_1d", strength=0), pdeinv.load_problem("heat_1d")
    x = heat.sample(16, seed=0)[0]
    assert _rel(ac.operator.forward(x), heat.operator.forward(x)) <= 1e-12
    sg = pdeinv.load_problem("sine_gordon_1d", strength=0, steps=100)
    wave = pdeinv.load_problem("wave_1d", scheme="leapfrog", backend="steps")
    assert _rel(sg.operator.forward(x), wave.operator.forward(x)) <= 1e-12
    ac2, heat2 = pdeinv.load_problem("allen_cahn_2d", strength=0, n=6), pdeinv.load_problem(
        "heat_2d", n=6, steps=50, backend="steps")
    x2 = heat2.sample(4, seed=0)[0]
    assert _rel(ac2.operator.forward(x2), heat2.operator.forward(x2)) <= 1e-12


@pytest.mark.parametrize("name", ["allen_cahn_1d", "sine_gordon_1d"])
def test_defaults_are_clearly_nonlinear(name):
    """The linearization at 0 misses P(x) by more than 20 % (median over prior draws)."""
    p = pdeinv.load_problem(name)
    x, y = p.sample(16, seed=1)
    lin = p.operator.jvp(np.zeros_like(x), x)
    assert np.median(np.linalg.norm(y - lin, axis=1) / np.linalg.norm(y, axis=1)) >= 0.2


def test_linearity_is_declared():
    d = _disc(8)
    heat = pdeinv.physics.Heat(d.M, d.K, steps=5, backend="steps", dim=1)
    assert is_linear(heat) and not is_linear(ReactionHeat(d.M, d.K, steps=5))
    # a linear operator is a Physics whose tangent is itself
    X = np.random.default_rng(0).standard_normal((2, d.N))
    assert np.array_equal(heat.jvp(X, X), heat.forward(X))
    assert np.array_equal(heat.vjp(X, X), heat.adjoint(X))
    with pytest.raises(NotImplementedError, match="declares linear=False"):
        require_linear(ReactionHeat(d.M, d.K, steps=5), "a Wiener target")
    with pytest.raises(TypeError, match="does not declare `linear`"):
        is_linear(sp.identity(3))
    p = pdeinv.load_problem("allen_cahn_1d", steps=5)
    assert not hasattr(p.operator, "choice")  # the Problem compiled nothing


def test_per_sample_jacobians_through_vmap():
    """HIG's route: ``vmap(jacrev(P))`` over samples gives each sample's tangent ``P'(x_b)``."""
    d = discretize(pdeinv.mesh.interval(8))
    op = SineGordon(lumped_mass(d), d.K, T=0.2, strength=50.0)
    x = torch.tensor(_draw(op, b=3), dtype=torch.float64)
    J = torch.func.vmap(torch.func.jacrev(lambda t: pdeinv.apply(op, t)))(x).numpy()
    eye = np.eye(op.n_in)
    for b in range(3):
        ref = op.jvp(np.repeat(x[b : b + 1].numpy(), op.n_in, axis=0), eye).T  # columns P'(x_b) e_i
        assert np.allclose(J[b], ref, rtol=0, atol=1e-13)


def test_a_vjp_after_a_forward_at_the_same_point_reuses_its_checkpoints():
    d = _disc(16)
    op = ReactionHeat(d.M, d.K, steps=16, strength=2.0)
    X = _draw(op, b=2)
    R = np.random.default_rng(0).standard_normal(X.shape)
    fresh = op.vjp(X, R)
    op.forward(X)
    calls = []
    op.step = (lambda step: lambda *a, **k: calls.append(1) or step(*a, **k))(op.step)
    assert np.array_equal(op.vjp(X, R), fresh)
    assert len(calls) == 16  # the segments only: no checkpoint run
    X2 = X.copy()
    X2[0, 0] += 1e-3  # another point: recomputed
    calls.clear()
    op.vjp(X2, R)
    assert len(calls) == 32


# -- the chord solver (one frozen factorization) against block-LU Newton --------------------------------

def _pair(n=32, **kw):
    d = _disc(n)
    return (ReactionHeat(d.M, d.K, solver="chord", **kw), ReactionHeat(d.M, d.K, solver="newton", **kw))


@pytest.mark.parametrize("kw,amp", [({}, 1.0), ({"strength": 5.0, "steps": 40}, 2.0),
                                    ({"strength": 5.0, "steps": 40, "scheme": "cn"}, 2.0)])
def test_chord_equals_newton_forward_jvp_and_vjp(kw, amp):
    """The chord iteration (frozen ``A_c``) and the Richardson tangent solves reach the block-LU
    Newton answers to 1e-12 relative, at the scene's defaults and at r = 5 (amplitude 2: the first
    steps' largest columns fall back to Newton, the others are the chord's)."""
    chord, newton = _pair(**kw)
    X = _draw(chord, b=6, amp=amp)
    rng = np.random.default_rng(4)
    V, R = rng.standard_normal(X.shape), rng.standard_normal(X.shape)
    assert _rel(chord.forward(X), newton.forward(X)) <= 1e-12
    assert max(chord.chord_iterations) >= 2 and not any(chord.newton_iterations[3:])
    assert _rel(chord.jvp(X, V), newton.jvp(X, V)) <= 1e-12
    assert _rel(chord.vjp(X, R), newton.vjp(X, R)) <= 1e-12
    ref, tangent = newton.linearize(X)
    out, frozen = chord.linearize(X)
    assert _rel(out, ref) <= 1e-12
    assert _rel(frozen.jvp(V), tangent.jvp(V)) <= 1e-12 and _rel(frozen.vjp(R), tangent.vjp(R)) <= 1e-12


def test_chord_equals_newton_on_the_scene_defaults():
    """The default solver: Newton on tridiagonal blocks (allen_cahn_1d, P1), the chord on wider ones (P2,
    2-D), whichever was measured faster; the chord gives the same fields to 1e-12 without falling back."""
    p = pdeinv.load_problem("allen_cahn_1d")
    op = p.operator
    assert op.solver.name == "newton"
    assert pdeinv.load_problem("allen_cahn_1d", element="P2", steps=5).operator.solver.name == "chord"
    assert pdeinv.load_problem("allen_cahn_2d", n=8, steps=5).operator.solver.name == "chord"
    chord = ReactionHeat(op.M, op.K, kappa=op.kappa, T=op.t_end, steps=op.steps, strength=op.strength,
                         solver="chord")
    X = p.sampler(16, np.random.default_rng(3))
    assert _rel(op.forward(X), chord.forward(X)) <= 1e-12
    assert max(chord.chord_iterations) <= 8 and chord.fallback_columns == 0


def test_chord_falls_back_to_newton_where_it_does_not_contract():
    """r = 10 and amplitude 3: ``θ dt max|f' − c| ‖A_c⁻¹M‖`` is near 1, the chord's update ratio
    exceeds ½, and those columns (steps and tangent solves) are solved by block-LU Newton: the same
    answers; a mixed batch falls back for the large column only."""
    chord, newton = _pair(strength=10.0, steps=40)
    X = _draw(chord, b=3, amp=3.0)
    X[1] *= 0.1  # a small column: contracts
    R = np.random.default_rng(6).standard_normal(X.shape)
    assert _rel(chord.forward(X), newton.forward(X)) <= 1e-12
    assert any(chord.newton_iterations) and 1 <= chord.fallback_columns < 3 * chord.steps
    assert _rel(chord.vjp(X, R), newton.vjp(X, R)) <= 1e-12
    assert _rel(chord.jvp(X, R), newton.jvp(X, R)) <= 1e-12
    chord.fallback_columns = 0
    chord.solver.tangent(chord, 3.0 * X.T.copy()).solve(R.T.copy())  # f'(3x) far from any c
    assert chord.fallback_columns >= 1


def test_chord_refuses_an_unknown_solver():
    d = _disc(8)
    with pytest.raises(ValueError, match="solver"):
        ReactionHeat(d.M, d.K, steps=5, solver="jacobi")


def test_newton_reaches_the_answer_from_far_out():
    """A network's output may be far out (a bad training step): Newton on the cubic reduces a large
    error by about a third per iteration before its quadratic phase, so amplitude 1000 takes ~50
    iterations (max_newton = 100; with 30, HIG on allen_cahn_1d stopped at step 21). The step's answer
    is then in the reaction's range."""
    p = pdeinv.load_problem("allen_cahn_1d")
    X = 1000.0 * np.random.default_rng(0).standard_normal((4, p.N))
    Y = p.operator.forward(X)
    assert np.all(np.isfinite(Y)) and np.abs(Y).max() < 1.5 and max(p.operator.newton_iterations) > 30


@pytest.mark.parametrize("element,band", [("P1", 1), ("P2", 2)])
def test_banded_block_factors_solve_as_superlu_does(monkeypatch, element, band):
    """1-D blocks are banded after reverse Cuthill–McKee: LAPACK's tridiagonal (P1) or band (P2) LU
    solves the block-diagonal Jacobian and its transpose as SuperLU does, to 1e-13."""
    import pdeinv.physics.reaction as reaction

    d = discretize(pdeinv.mesh.interval(24), element)
    op = ReactionHeat(d.M, d.K, steps=10, strength=3.0)
    assert op.blocks.band == band
    rng = np.random.default_rng(0)
    D, v = rng.uniform(-3, 6, (op.n_in, 5)), rng.standard_normal(op.n_in * 5)
    fast = op.blocks.jacobian(0.1, D)
    monkeypatch.setattr(reaction, "BANDED_MAX", 0)
    slow = op.blocks.jacobian(0.1, D)
    assert isinstance(fast, reaction._BandFactor) and isinstance(slow, reaction._Factor)
    for trans in "NT":
        assert _rel(fast.solve(v, trans), slow.solve(v, trans)) <= 1e-13


def test_kept_exact_factors_give_the_chords_tangent(monkeypatch):
    """``linearize`` keeps every step's exact block factors where they fit (KEPT_FACTORS_BYTES), else
    the chord's Richardson tangent: the same products to 1e-12, and both the exact transposes."""
    import pdeinv.physics.reaction as reaction

    op = ReactionHeat(_disc().M, _disc().K, steps=40, strength=5.0, solver="chord")
    X = _draw(op, b=6, amp=2.0)
    rng = np.random.default_rng(5)
    V, R = rng.standard_normal(X.shape), rng.standard_normal(X.shape)
    _, exact = op.linearize(X)
    monkeypatch.setattr(reaction, "KEPT_FACTORS_BYTES", 0)
    _, frozen = op.linearize(X)
    assert all(isinstance(t, reaction._BlockTangent) for t in exact.lus)
    assert not any(isinstance(t, reaction._BlockTangent) for t in frozen.lus)
    assert _rel(exact.jvp(V), frozen.jvp(V)) <= 1e-12 and _rel(exact.vjp(R), frozen.vjp(R)) <= 1e-12
    assert abs(np.sum(exact.jvp(V) * R) - np.sum(V * exact.vjp(R))) <= 1e-12 * np.abs(exact.jvp(V)).max()


@pytest.mark.parametrize("kw", [{}, {"scheme": "cn"}, {"element": "P2"}, {"banded": False}, {"kept": False}])
def test_per_row_jacobians_are_the_vjps_of_every_unit_cotangent(monkeypatch, kw):
    """``jacobian(X)``: row ``j`` of ``P'(x_b)`` is the vjp of ``e_j`` at ``x_b``, to 1e-12 relative (the
    vjp's chord tangent stops each step's Richardson iteration at 1e-14: 2e-13 seen), on
    backward Euler and Crank–Nicolson, P1 and P2, SuperLU's blocks and the banded ones, and where
    ``linearize`` kept only the chord's tangent (the factors are then made per step)."""
    import pdeinv.physics.reaction as reaction

    kw = dict(kw)
    if not kw.pop("banded", True):
        monkeypatch.setattr(reaction, "BANDED_MAX", 0)
    if not kw.pop("kept", True):
        monkeypatch.setattr(reaction, "KEPT_FACTORS_BYTES", 0)
    element = kw.pop("element", "P1")
    d = discretize(pdeinv.mesh.interval(12), element)
    op = ReactionHeat(d.M, d.K, steps=15, strength=4.0, **kw)
    X = _draw(op, b=4, amp=1.5)
    J = op.jacobian(X)
    assert J.shape == (4, op.n_out, op.n_in)
    for b in range(4):
        ref = op.vjp(np.repeat(X[b : b + 1], op.n_out, axis=0), np.eye(op.n_out))
        assert _rel(J[b], ref) <= 1e-12


def test_sine_gordon_per_row_jacobians_are_the_vjps_of_every_unit_cotangent():
    """The transposed leapfrog on all unit cotangents at once: row ``j`` of ``P'(x_b)`` is the vjp of
    ``e_j`` at ``x_b`` to 1e-13 relative, and ``P'(x_b) v`` the jvp."""
    d = discretize(pdeinv.mesh.interval(12))
    op = SineGordon(lumped_mass(d), d.K, T=0.5, strength=20.0)
    X = _draw(op, b=3)
    J = op.jacobian(X)
    assert J.shape == (3, op.n_out, op.n_in)
    V = np.random.default_rng(1).standard_normal(X.shape)
    assert _rel(np.einsum("bij,bj->bi", J, V), op.jvp(X, V)) <= 1e-13
    for b in range(3):
        assert _rel(J[b], op.vjp(np.repeat(X[b : b + 1], op.n_out, axis=0), np.eye(op.n_out))) <= 1e-13
