"""The local-inverse contract (DESIGN.md; issue 32 item 3) for every inverse pdeinv ships.

``P⁻¹_(x₀, P x₀)(P x₀) = x₀`` to rounding, from random ``x₀`` (white noise: in no prior's span, no
decoder's span, no smooth subspace), for every inverse class and every built-in scene's default
``problem.inverse`` and SIP default inverse; the inverse is *local*: its output minus ``x₀`` is the
inverse of the residual alone, and whatever of ``x₀`` the physics (or the decoded physics ``P̂ = P D``)
cannot see is carried over, not zeroed. The old ``DecoderTikhonov`` (``x̃ = D V diag(s/(s²+α)) Qᵀ y``,
``x₀`` ignored) fails all three.
"""

import numpy as np
import pytest

import pdeinv
import pdeinv.inverse as inv
from pdeinv import nets
from pdeinv.inverse import (
    Discrepancy,
    RelativeAlpha,
    ReusesForward,
    SpectralTikhonov,
    StateReversal,
    TikhonovCG,
    TimeReversal,
)
from pdeinv.inverse.decoder import DecoderTikhonov
from pdeinv.problem.definition import available

#: every built-in scene, small (default backend unless the key says otherwise)
SCENES = {
    "advection_diffusion_2d": dict(n=6, steps=5),
    "allen_cahn_1d": dict(n=16, steps=10),
    "allen_cahn_2d": dict(n=6, steps=5),
    "sine_gordon_1d": dict(n=16),
    "sine_gordon_2d": dict(n=6),
    "heat_1d": dict(n=16, steps=10),
    "heat_1d-modal": dict(n=16, steps=10, backend="modal"),
    "heat_2d": dict(n=6, steps=5),
    "heat_2d-steps": dict(n=6, steps=5, backend="steps"),
    "heat_3d": dict(n=3, steps=5),
    "heat_boxes": dict(n=8, steps=5),
    "heat_cavity_3d": dict(steps=3),
    "heat_plate": dict(refine=0, steps=5),
    "heat_sensors_2d": dict(n=6, steps=6, record_every=2, sensors=5),
    "heat_sensors_3d": dict(n=3, steps=6, record_every=2, sensors=5),
    "reaction_diffusion_2d": dict(n=6, steps=5),
    "wave_1d": dict(n=16, steps=8),
    "wave_2d": dict(n=6, steps=8),
    "wave_2d-steps": dict(n=6, steps=8, backend="steps"),
    "wave_3d": dict(n=3, steps=5),
    "wave_sensors_2d": dict(n=6, steps=12, sensors=8, record_every=2),
}

#: relative tolerance of ``inverse(P x₀, x₀) = x₀`` in ‖·‖_M; every residual-form inverse is exact
#: (the residual is exactly zero), time reversal and its compiled matrix to rounding
TOL = 1e-10


def scene(key):
    return pdeinv.load_problem(key.split("-")[0], **SCENES[key])


def white(p, B=4, seed=0):
    """Random ``x₀`` of white noise: in no special subspace."""
    return np.random.default_rng(seed).standard_normal((B, p.N))


def test_every_builtin_scene_is_listed():
    assert {k.split("-")[0] for k in SCENES} >= set(available())


@pytest.fixture(scope="module")
def problems():
    return {}


def get(problems, key):
    if key not in problems:
        problems[key] = scene(key)
    return problems[key]


@pytest.mark.parametrize("key", list(SCENES))
def test_each_scene_default_inverse_returns_x0(problems, key):
    """``problem.inverse(P x₀, x₀) = x₀`` and the same for the inverse SIP uses by default with the scene's
    default network (the decoder's span for the heat scenes, the problem's own otherwise)."""
    p = get(problems, key)
    x0 = white(p)
    y0 = p.operator.forward(x0)
    assert np.max(p.relative_error(p.inverse(y0, x0), x0)) <= TOL
    context = pdeinv.SIP().context(p, p.model())
    assert np.max(p.relative_error(context.inverse(y0, x0), x0)) <= TOL
    if context.local is not None:  # the route SIP takes: its own P x passed in
        assert np.max(p.relative_error(context.local(y0, x0, y0), x0)) <= TOL


# -- every inverse class: (problem key, factory(problem) -> (inverse, forward)) -----------------------

def _plain(make):
    return lambda p: (make(p), p.operator.forward)


def _full_state(p):
    def forward(X):
        return np.hstack(p.operator.final_state(X))

    return StateReversal(p.operator), forward


def _decoder(p):
    model = nets.reduced(k_in=8, k_out=10)(p)
    return DecoderTikhonov(p.operator, model.linear_in_parameters().decoder), p.operator.forward


CLASSES = {
    "ModalTikhonov": ("heat_1d-modal", _plain(lambda p: inv.ModalTikhonov(p.operator, RelativeAlpha(1e-12)))),
    "SpectralTikhonov": ("heat_sensors_2d", _plain(lambda p: SpectralTikhonov(
        p.operator, RelativeAlpha(1e-12), modes=p.inverse_simulator.modes))),
    "SpectralTikhonov-discrepancy": ("heat_sensors_2d", _plain(lambda p: SpectralTikhonov(
        p.operator, Discrepancy(0.01), modes=p.inverse_simulator.modes))),
    "TikhonovCG": ("heat_2d-steps", _plain(lambda p: TikhonovCG(p.operator, p.disc.M, 1e-8))),
    "TikhonovCG-discrepancy": ("heat_2d-steps", _plain(lambda p: TikhonovCG(p.operator, p.disc.M,
                                                                            Discrepancy(0.01)))),
    "TimeReversal": ("wave_2d-steps", _plain(lambda p: TimeReversal(p.operator))),
    "StateReversal": ("wave_2d-steps", _full_state),
    "DecoderTikhonov": ("heat_1d", _decoder),
    "DecoderTikhonov-identity": ("heat_2d", _plain(lambda p: DecoderTikhonov(p.operator, None,
                                                                             rel_alpha=1e-12))),
}


def test_every_shipped_inverse_is_listed():
    shipped = {name for name in inv.__all__ if isinstance(getattr(inv, name), type)
               and name not in {"Discrepancy", "FixedAlpha", "RelativeAlpha", "ReusesForward"}}
    assert {k.split("-")[0] for k in CLASSES} >= shipped | {"DecoderTikhonov"}


@pytest.mark.parametrize("name", list(CLASSES))
def test_each_inverse_returns_x0(problems, name):
    key, factory = CLASSES[name]
    p = get(problems, key)
    inverse, forward = factory(p)
    x0 = white(p, seed=1)
    y0 = forward(x0)
    assert np.max(p.relative_error(inverse(y0, x0), x0)) <= TOL
    assert np.max(p.relative_error(inverse(y0[0], x0[0])[None], x0[:1])) <= TOL  # one sample in, one out
    if isinstance(inverse, ReusesForward):  # the caller's y₀ changes nothing but the cost
        y = y0 + np.random.default_rng(2).standard_normal(y0.shape) * np.abs(y0).max()
        assert np.max(p.relative_error(inverse.local(y0, x0, y0), x0)) <= TOL
        assert np.allclose(inverse.local(y, x0, y0), inverse(y, x0), rtol=1e-12, atol=0)


#: inverses linear in the residual: a fixed α (a discrepancy α depends on y itself)
LINEAR = [n for n in CLASSES if not n.endswith("discrepancy")]


@pytest.mark.parametrize("name", LINEAR)
def test_the_change_is_the_inverse_of_the_residual(problems, name):
    """``inverse(P x₀ + δ, x₀) − x₀ = inverse(δ, 0)`` for a small ``δ``: the change depends on the
    residual alone, linearly (doubling δ doubles it) — the prediction ``x₀`` is moved, never replaced."""
    key, factory = CLASSES[name]
    p = get(problems, key)
    inverse, forward = factory(p)
    x0 = white(p, seed=3)
    y0 = forward(x0)
    delta = 1e-3 * np.abs(y0).max() * np.random.default_rng(4).standard_normal(y0.shape)
    change = inverse(y0 + delta, x0) - x0
    alone = inverse(delta, np.zeros_like(x0))
    scale = p.disc.norm(alone) + 1e-6 * p.disc.norm(x0)  # rounding of x₀ + Δx − x₀, amplified by the filter
    assert np.max(p.disc.norm(change - alone) / scale) <= 1e-7
    assert np.max(p.disc.norm(inverse(2 * delta, np.zeros_like(x0)) - 2 * alone) / scale) <= 1e-7
    assert np.min(p.disc.norm(alone) / p.disc.norm(x0)) > 1e-6  # a change that is really there


# -- what the physics cannot see is kept ---------------------------------------------------------------

@pytest.fixture(scope="module")
def blind():
    """heat_sensors_2d with 4 sensors, one record: ``P`` is 4 × 49, a 45-dimensional null space."""
    return pdeinv.load_problem("heat_sensors_2d", n=8, steps=6, sensors=4, record_every=6)


def null_basis(A, rel=1e-13):
    """Orthonormal columns spanning ``{v : A v = 0}`` (to ``rel`` of ``A``'s largest singular value)."""
    _, s, Vt = np.linalg.svd(A)
    rank = int(np.sum(s > rel * s[0]))
    return Vt[rank:].T


@pytest.mark.parametrize("which", ["decoder", "identity-decoder", "spectral", "cg"])
def test_the_null_space_component_of_x0_is_kept(blind, which):
    """``inverse(y, x₀ + n) = inverse(y, x₀) + n`` for ``n`` the physics cannot see (``P n = 0``; for the
    decoder inverse ``n = D c`` with ``P̂ c = 0``) and any ``y``: the change does not touch it. The old
    global decoder map returned the same field for both, i.e. zeroed ``n``."""
    p, op = blind, blind.operator
    rng = np.random.default_rng(5)
    if which == "decoder":
        decoder = nets.reduced(k_in=4, k_out=12)(p).linear_in_parameters().decoder  # 12 components > 4 rows
        D = decoder.detach().double().numpy().T  # (N, k)
        inverse = DecoderTikhonov(op, decoder, rel_alpha=1e-12)
        C = null_basis(op.forward(D.T).T)  # null space of P̂ = P D, in coefficients
        assert C.shape[1] >= 8
        n = (C @ rng.standard_normal((C.shape[1], 3))).T @ D.T
    else:
        inverse = {"identity-decoder": lambda: DecoderTikhonov(op, None, rel_alpha=1e-12),
                   "spectral": lambda: SpectralTikhonov(op, RelativeAlpha(1e-12),
                                                        modes=p.inverse_simulator.modes),
                   "cg": lambda: TikhonovCG(op, p.disc.M, RelativeAlpha(1e-12))}[which]()
        Z = null_basis(op.forward(np.eye(p.N)).T)
        assert Z.shape[1] == p.N - op.n_out
        n = (Z @ rng.standard_normal((Z.shape[1], 3))).T
    x0 = white(p, B=3, seed=6)
    n *= p.disc.norm(x0)[:, None] / p.disc.norm(n)[:, None]  # as large as x₀
    y = op.forward(white(p, B=3, seed=7))  # any observation
    kept = inverse(y, x0 + n) - inverse(y, x0)
    assert np.max(p.relative_error(kept, n)) <= 1e-8


@pytest.mark.parametrize("name", ["heat_plate", "wave_2d"])
def test_the_forward_in_the_decoders_span_is_the_physics(problems, name):
    """DecoderTikhonov.forward_in_span: P x from P D's SVD for x = D c, equal to the physics to rounding;
    a field outside the span keeps only its projection."""
    p = get(problems, name) if name == "heat_plate" else pdeinv.load_problem(name, n=12)
    D = pdeinv.nets.reduced(k_in=8, k_out=24, k_max=24)(p).post.basis.double().numpy()  # (k, N)
    inv = DecoderTikhonov(p.operator, D)
    c = np.random.default_rng(1).standard_normal((5, D.shape[0]))
    direct = p.operator.forward(c @ D)
    assert np.abs(inv.forward_in_span(c @ D) - direct).max() < 1e-10 * np.abs(direct).max()
    x = np.random.default_rng(2).standard_normal((3, p.N))
    proj = np.linalg.lstsq(D.T, x.T, rcond=None)[0].T @ D
    assert np.allclose(inv.forward_in_span(x), p.operator.forward(proj), atol=1e-10 * np.abs(direct).max())


def test_sip_passes_its_forward_to_the_inverse(problems, monkeypatch):
    """SIP's default inverse (:class:`ReusesForward`) gets the ``P x`` SIP computed for its loss, and that
    ``P x`` comes from ``P D`` (the network's fields lie in the decoder's span): no physics call per step
    against two through the plain ``inverse(y, x0)``, and the same step."""
    import torch

    p = get(problems, "heat_plate")
    op, calls = p.operator, []
    forward = op.forward
    monkeypatch.setattr(op, "forward", lambda X: calls.append(len(X)) or forward(X))
    _, y = p.sample(16, seed=8)
    Y = torch.as_tensor(y)
    steps = {}
    for route in ("local", "plain"):
        torch.manual_seed(0)
        model = pdeinv.nets.fit_preconditioning(p.model(), y)
        rule = pdeinv.SIP()
        state = rule.init(p, model)
        assert isinstance(state.context.inverse, DecoderTikhonov)
        if route == "plain":
            rule = pdeinv.SIP(inverse=lambda y, x0, _inv=state.context.inverse: _inv(y, x0))
            state = rule.init(p, model)
            assert state.context.local is None
        x = model(Y).detach().numpy().copy()
        calls.clear()
        rule.step(state, model, Y)
        steps[route] = (len(calls), model(Y).detach().numpy() - x)
    assert (steps["local"][0], steps["plain"][0]) == (0, 2), steps
    change = steps["plain"][1]
    assert np.allclose(steps["local"][1], change, rtol=1e-6, atol=1e-9 * np.abs(change).max())
    assert np.abs(steps["local"][1]).max() > 0


def test_sip_in_decoder_coordinates_is_the_field_step(problems):
    """With the default inverse on the network's own decoder, SIP's step runs in the decoder's coordinates
    (``SIP._update_in_span``: ``P̂ c``, ``Δc``, the proxy through ``DᵀD``) and equals the step on the fields
    (the same context without ``span``, the physics' own forward) to rounding: gradient, loss and proxy;
    with the observations and with another ``target``. (Unnormalized: the Jacobi scaling divides by the
    decoder's weakest columns, where the field route's ``x − x̃``, formed from two ``(B, N)`` fields, rounds
    at ``eps·|x|``; the coordinates are the more accurate route.)"""
    import torch

    p = get(problems, "heat_plate")
    _, y = p.sample(16, seed=9)
    Y = torch.as_tensor(y)
    torch.manual_seed(0)
    model = pdeinv.nets.fit_preconditioning(p.model(), y)
    with torch.no_grad():  # a non-trivial network: its fields are not the zero field
        for q in model.parameters():
            q.add_(1e-3 * torch.randn_like(q))
    rule = pdeinv.SIP(eta=0.7, normalize=False)
    state = rule.init(p, model)
    assert state.context.span is state.context.inverse
    fields = state._replace(context=state.context._replace(span=None, forward=None))  # the physics
    for target in (None, Y + 0.01 * Y.std() * torch.randn_like(Y)):
        a, b = rule.update(state, model, Y, target), rule.update(fields, model, Y, target)
        for da, db in zip(a.direction, b.direction, strict=True):
            assert float((da - db).abs().max()) <= 1e-7 * float(db.abs().max())
        assert a.info["loss"] == pytest.approx(b.info["loss"], rel=1e-10)
        assert a.info["proxy"] == pytest.approx(b.info["proxy"], rel=1e-8)
        assert b.info["proxy"] > 0


def test_held_out_observations_come_from_the_decoded_physics(problems, monkeypatch):
    """The trainer's evaluation and stopping residual take ``P f(y)`` from the run's ``P D`` where the
    network ends in that decoder (no physics call), equal to the physics' own to rounding; without a
    computed ``P D`` the physics runs."""
    import torch

    from pdeinv.inverse.decoder import decoded_svd
    from pdeinv.training.stopping import observe

    p = get(problems, "heat_plate")
    _, y = p.sample(8, seed=10)
    Y = torch.as_tensor(y)
    model = pdeinv.nets.fit_preconditioning(p.model(), y)
    with torch.no_grad():
        for q in model.parameters():
            q.add_(1e-3 * torch.randn_like(q))
    op, calls = p.operator, []
    forward = op.forward
    monkeypatch.setattr(op, "forward", lambda X: calls.append(len(X)) or forward(X))
    x, direct = observe(op, model, Y)
    assert calls == [8]
    decoded_svd(op, model.decoder)  # what SIP's inverse and the target compute once per run
    calls.clear()
    x2, decoded = observe(op, model, Y)
    assert calls == [] and np.array_equal(x, x2)
    assert np.abs(decoded - direct).max() <= 1e-10 * np.abs(direct).max()
