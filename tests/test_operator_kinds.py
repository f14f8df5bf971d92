"""One operator kind, one backend chooser (issue 24, items 1 and 3).

* ``Heat`` is a :class:`~pdeinv.physics.Propagator`; the modal form is a compiled kind offered
  whenever the scheme's matrices are symmetric, so a reaction–diffusion scene written the cheap
  way (``C = rM``) gets it from ``auto``;
* a spectral basis is one declared class (:class:`~pdeinv.physics.capabilities.Spectral`);
* an operator built by hand is compiled by ``auto`` once it becomes part of a Problem or gets
  its local inverse: it trains at the scenes' speed without anyone calling ``.compile``.
"""

from functools import partial

import numpy as np
import pytest

import pdeinv
from pdeinv import observe
from pdeinv.fem.forms import discretize
from pdeinv.inverse import SpectralTikhonov, default_inverse
from pdeinv.physics import Heat, Modal, Propagator, Wave
from pdeinv.physics.capabilities import Spectral, modal_basis
from pdeinv.problem.definition import Problem, load_problem
from pdeinv.problem.sampling import gaussian_bumps


def _rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def test_heat_is_a_propagator_with_the_one_loop():
    """The stepping heat operator is the Propagator itself, and it is backward Euler: ten solves of
    ``(M + dt κ K) u⁺ = M u`` by a plain SciPy loop give the same final field."""
    import scipy.sparse.linalg as sla

    d = discretize(pdeinv.fem.mesh.unit_square(6))
    op = Heat(d.M, d.K, kappa=0.01, T=1.0, steps=10, backend="steps")
    assert isinstance(op, Propagator) and op.kind == "steps" and op.backend is None
    assert op.stepping() is op
    x = np.random.default_rng(0).standard_normal((3, op.n_in))
    lu, u = sla.splu((d.M + 0.1 * 0.01 * d.K).tocsc()), x.T
    for _ in range(10):
        u = lu.solve(d.M @ u)
    assert _rel(op.forward(x), u.T) < 1e-12


@pytest.mark.parametrize("scheme", ["be", "cn"])
def test_reaction_diffusion_written_the_cheap_way_gets_the_modal_backend(scheme):
    """``M u' + (κK + rM) u = 0`` as ``Heat(..., C=r*M)``: symmetric matrices, so ``auto`` takes the
    modal form (it used to be refused for any ``C``), equal to time stepping and its own transpose;
    each mode decays by ``r(dt(κλ + r))ⁿ``."""
    d = discretize(pdeinv.fem.mesh.unit_square(16))
    r, kw = 2.0, dict(kappa=0.01, steps=50, scheme=scheme, measure=d.measure, dim=d.dim)
    op = Heat(d.M, d.K, C=r * d.M, **kw)
    assert op.symmetric and op.kind == "modal", op.choice
    assert op.choice.startswith("auto: modal") and isinstance(modal_basis(op), Spectral)
    ref = Heat(d.M, d.K, C=r * d.M, backend="steps", **kw)
    rng = np.random.default_rng(0)
    X, R = rng.standard_normal((3, d.N)), rng.standard_normal((3, d.N))
    assert _rel(op.forward(X), ref.forward(X)) <= 1e-10 and _rel(op.adjoint(R), ref.adjoint(R)) <= 1e-10
    plain = Heat(d.M, d.K, backend="modal", **kw)  # the same modes, shifted by r: μ = κλ + r
    np.testing.assert_allclose(op.modes.lam[:5], plain.modes.lam[:5] + r, rtol=1e-10)
    assert type(default_inverse(op, d)) is SpectralTikhonov


def test_reaction_diffusion_scene_is_one_builder_line():
    p = load_problem("reaction_diffusion_2d", n=12, steps=20)
    assert p.operator.kind == "modal" and type(p.inverse_simulator) is SpectralTikhonov, p.operator.choice
    x, y = p.sample(2, seed=0)
    np.testing.assert_allclose(p.inverse(p.operator.forward(x), x), x, atol=1e-12)  # exact at y₀
    d, r = p.disc, p.settings["reaction"]
    ref = Heat(d.M, d.K, kappa=0.01, steps=20, C=r * d.M, backend="steps")  # the reaction is in the map
    assert r == 1.0 and _rel(y, ref.forward(x)) <= 1e-10


def test_convection_still_has_no_modal_form():
    p = load_problem("advection_diffusion_2d", n=6, steps=10, speed=2.0)
    assert not p.operator.symmetric and p.operator.kind != "modal" and "modal" not in p.operator.choice
    with pytest.raises(ValueError, match="backend='modal' needs a symmetric operator"):
        p.operator.compile("modal")


def test_sensor_and_wave_runs_have_no_modal_form():
    d = discretize(pdeinv.fem.mesh.unit_square(6))
    S = observe.sensor_matrix(d, [[0.5, 0.5]])
    with pytest.raises(ValueError, match="records sensors"):
        Modal(Heat(d.M, d.K, steps=10, backend="steps").sensors(S, 5))
    with pytest.raises(ValueError, match="not a θ-scheme"):
        Wave(d.M, d.K, steps=10).compile("modal")


def _hand_built(n=16, sensors=12, with_inverse=False):
    """A new user's module: unit square, Dirichlet on the left edge only, 12 sensors, ``.sensors(S, 10)``."""
    m = pdeinv.fem.mesh.unit_square(n).with_boundaries({"left": lambda x: np.isclose(x[0], 0.0)})
    disc = discretize(m, dirichlet="left")
    S = observe.sensor_matrix(disc, observe.interior_points(m, sensors))
    op = Heat(disc.M, disc.K, kappa=0.05, T=1.0, steps=100, backend="steps",
              measure=disc.measure, dim=disc.dim).sensors(S, 10)
    assert op.backend is None  # nobody chose a backend yet
    inverse = default_inverse(op, disc) if with_inverse else None
    return Problem("mine", disc, op, partial(gaussian_bumps, disc.points), inverse_simulator=inverse)


@pytest.mark.parametrize("with_inverse", [False, True])
def test_a_hand_built_sensor_operator_goes_through_the_chooser(with_inverse):
    """Issue 24: such a module trained SIP at 2.9 s/step against 0.0028 s/step once ``.compile('auto',
    disc.M)`` was copied from the scenes. Now the Problem (or the default inverse) compiles it by
    ``auto``, in the norms of ``disc.M``: the kind the scene would get, and the spectral inverse."""
    scene = load_problem("heat_sensors_2d", n=16, sensors=12)
    mine = _hand_built(with_inverse=with_inverse)
    assert mine.operator.backend is not None and mine.operator.backend.name == scene.operator.backend.name
    assert mine.operator.choice.startswith("auto: ") and mine.operator.modes.mass_out is None
    if with_inverse:
        assert type(mine.inverse_simulator) is SpectralTikhonov  # the fast SIP step: a filter, not CG
    x, y = mine.sample(2, seed=0)
    ref = mine.operator.stepping()
    assert ref is not mine.operator and _rel(mine.operator.forward(x), ref.forward(x)) <= 1e-10


def test_a_hand_built_wave_is_compiled_by_the_problem_and_an_explicit_choice_is_kept():
    d = discretize(pdeinv.fem.mesh.unit_square(8))
    auto = Problem("w", d, Wave(d.M, d.K, steps=20), partial(gaussian_bumps, d.points))
    assert auto.operator.choice.startswith("auto: ") and auto.operator.kind == "dense", auto.operator.choice
    kept = Problem("w", d, Wave(d.M, d.K, steps=20).compile("steps"), partial(gaussian_bumps, d.points))
    assert kept.operator.kind == "steps" and kept.operator.choice == "backend='steps' requested"


def test_a_spectral_basis_is_one_declared_class():
    """The modal basis, the SVD and the lazy SVD of a dense map are all :class:`Spectral`; anything
    else (an object with look-alike attributes) is not a basis."""
    from pdeinv.physics.backends.compiled import spectral_basis

    d = discretize(pdeinv.fem.mesh.unit_square(6))
    heat = Heat(d.M, d.K, steps=10, backend="modal")
    svd = Heat(d.M, d.K, steps=10, backend="svd")
    dense = Heat(d.M, d.K, steps=10, backend="dense")
    assert all(isinstance(b, Spectral) for b in (heat.modes, svd.modes, spectral_basis(dense, d.M)))
    assert dense.modes is None and modal_basis(dense) is None

    class LookAlike(pdeinv.physics.Matrix):
        modes = type("Fake", (), {"g": np.ones(2), "In": np.eye(2), "out": np.eye(2), "synth": np.eye(2)})()

    assert modal_basis(LookAlike(np.eye(2))) is None
