"""Property-based checks (hypothesis) of the operators on random sizes, coefficients and batches:
linearity, the adjoint identity, and the local-inverse round trip ``inverse(P x₀, x₀) = x₀``."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pdeinv

heat_cases = st.fixed_dictionaries({
    "n": st.integers(3, 24),
    "kappa": st.floats(1e-3, 1.0),
    "T": st.floats(0.05, 2.0),
    "steps": st.integers(1, 30),
    "scheme": st.sampled_from(["be", "cn"]),
    "backend": st.sampled_from(["steps", "auto"]),
    "element": st.sampled_from(["P1", "P2"]),
})
wave_cases = st.fixed_dictionaries({
    "n": st.integers(3, 24),
    "c": st.floats(0.1, 3.0),
    "T": st.floats(0.05, 2.0),
    "steps": st.integers(1, 30),
    "element": st.sampled_from(["P1", "P2"]),
})
problems = st.one_of(
    st.tuples(st.sampled_from(["heat_1d", "heat_2d"]), heat_cases),
    st.tuples(st.sampled_from(["wave_1d", "wave_2d"]), wave_cases),
)
SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _load(case):
    name, kw = case
    if name.endswith("2d"):
        kw = {**kw, "n": min(kw["n"], 10)}
    return pdeinv.load_problem(name, **kw)


@SETTINGS
@given(case=problems, batch=st.integers(1, 5), seed=st.integers(0, 2**31 - 1))
def test_linear_and_adjoint(case, batch, seed):
    op = _load(case).operator
    rng = np.random.default_rng(seed)
    x, z = rng.standard_normal((2, batch, op.n_in))
    r = rng.standard_normal((batch, op.n_out))
    a = rng.uniform(-3, 3)
    Px = op.forward(x)
    scale = np.abs(Px).max() + np.abs(op.forward(z)).max()
    np.testing.assert_allclose(op.forward(a * x + z), a * Px + op.forward(z), atol=1e-11 * scale)
    denom = np.linalg.norm(Px) * np.linalg.norm(r)
    if denom > 1e-200:  # an operator that damps everything to underflow has nothing to test
        assert abs(np.vdot(Px, r) - np.vdot(x, op.adjoint(r))) <= 1e-12 * denom


@SETTINGS
@given(case=problems, batch=st.integers(1, 4), seed=st.integers(0, 2**31 - 1))
def test_inverse_round_trip(case, batch, seed):
    p = _load(case)
    x0 = np.random.default_rng(seed).standard_normal((batch, p.N))
    back = p.inverse(p.operator.forward(x0), x0)
    assert np.linalg.norm(back - x0) <= 1e-10 * np.linalg.norm(x0)
