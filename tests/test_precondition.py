"""PCA whitening of observations (pdeinv.nets.whitening) and noise-level estimation (pdeinv.inverse.noise)."""

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.inverse.noise import estimate_noise, marchenko_pastur_median, noise_variance
from pdeinv.methods import SIP, adam
from pdeinv.nets import Net, fit_preconditioning, whitened
from pdeinv.nets.whitening import Whitening
from pdeinv.training.checkpoint import Checkpoint


def _gaussian(n, m, seed=0, decades=8):
    """Samples with covariance C = Q diag(λ) Qᵀ, λ log-spaced over ``decades`` decades, and mean μ."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((m, m)))
    lam = np.logspace(0, -decades, m)
    mu = rng.standard_normal(m)
    y = mu + (rng.standard_normal((n, m)) * np.sqrt(lam)) @ Q.T
    return y, Q, lam, mu


def test_whitened_training_data_has_identity_covariance():
    """Fitted on y, the transform maps y to zero mean and identity covariance (all λ above the floor)."""
    y, *_ = _gaussian(4000, 20, decades=6)
    w = Whitening(20).double().fit(y)
    z = w(torch.as_tensor(y)).numpy()
    assert np.abs(z.mean(0)).max() < 1e-10
    assert np.allclose(np.cov(z.T), np.eye(20), atol=1e-9)
    assert w.info["kept"] == 20 and w.info["unit_scale"] == 20


def test_fitted_transform_recovers_the_known_covariance():
    """U D⁻² Uᵀ of the fit is the sample covariance, close to the true C for many samples."""
    y, Q, lam, mu = _gaussian(20000, 12, seed=1, decades=4)
    w = Whitening(12).double().fit(y)
    U, g = w.basis.numpy(), w.gain.numpy()
    C_fit = U @ np.diag(g**-2.0) @ U.T
    assert np.allclose(C_fit, np.cov(y.T), rtol=0, atol=1e-12)
    C_true = Q @ np.diag(lam) @ Q.T
    assert np.linalg.norm(C_fit - C_true) / np.linalg.norm(C_true) < 0.03
    assert np.allclose(w.mean.numpy(), mu, atol=0.02)


def test_relative_floor_caps_the_gain_of_weak_directions():
    """λ below rel_floor·max λ gets the gain 1/√(rel_floor·max λ), not 1/√λ."""
    y, *_ = _gaussian(3000, 16, seed=2, decades=12)
    w = Whitening(16, rel_floor=1e-6).double().fit(y)
    lam_fit = 1 / w.gain.numpy() ** 2
    top = lam_fit[0]
    assert np.isclose(lam_fit.min(), 1e-6 * top, rtol=1e-9)  # floored
    lam_data = np.linalg.svd(y - y.mean(0), compute_uv=False) ** 2 / (len(y) - 1)
    assert w.info["unit_scale"] == int((lam_data >= 1e-6 * lam_data[0]).sum()) < 16
    assert np.allclose(lam_fit[lam_data >= 1e-6 * top], lam_data[lam_data >= 1e-6 * top], rtol=1e-9)
    assert "relative" in w.info["floor_rule"]


def test_noise_floor_comes_from_the_noise_level():
    """With a relative noise level δ the floor is σ² = δ²/(1+δ²)·mean(y²), and drop·σ² removes directions."""
    y, *_ = _gaussian(3000, 16, seed=3, decades=12)
    w = Whitening(16, drop=0).double().fit(y, noise=0.05)
    sigma2 = noise_variance(y, 0.05)
    assert np.isclose(w.info["floor"], sigma2)
    assert np.isclose((1 / w.gain.numpy() ** 2).min(), sigma2, rtol=1e-9)
    d = Whitening(16, drop=1.0).double().fit(y, noise=0.05)
    lam = np.linalg.svd(y - y.mean(0), compute_uv=False) ** 2 / (len(y) - 1)
    assert d.info["kept"] == int((lam >= sigma2).sum()) < 16
    assert (d.gain.numpy() == 0).sum() == 16 - d.info["kept"]
    edge = Whitening(16).double().fit(y, noise=0.05)  # default: the Marchenko–Pastur edge
    assert edge.info["kept"] == int((lam >= (1 + np.sqrt(16 / 2999)) ** 2 * sigma2).sum())


def test_edge_drop_keeps_the_signal_and_removes_pure_noise_directions():
    """Rank-5 signal + white noise: the default drop keeps exactly the 5 signal directions."""
    rng = np.random.default_rng(7)
    n, m = 2000, 200
    signal = rng.standard_normal((n, 5)) @ rng.standard_normal((5, m))
    signal /= np.sqrt((signal**2).mean(1, keepdims=True))  # equal rms: the relative noise is white
    delta = 0.05
    y = signal + delta * rng.standard_normal((n, m))
    assert Whitening(m).double().fit(y, noise=delta).info["kept"] == 5
    assert Whitening(m, drop=0).double().fit(y, noise=delta).info["kept"] == m


def test_rank_deficient_data_drops_the_unvisited_directions():
    """Fewer samples than observations: rank n − 1, the other directions get gain 0, outputs stay finite."""
    y, *_ = _gaussian(10, 30, seed=4, decades=2)
    w = Whitening(30).double().fit(y)
    assert w.info["kept"] == 9  # centred: rank n − 1
    assert w.basis.shape == (30, 30)
    B = w.basis.numpy()[:, :10]  # the n data directions (the centred rank n − 1, and one more)
    assert np.allclose(B.T @ B, np.eye(10), atol=1e-12)
    assert np.all(w.gain.numpy()[9:] == 0)  # the unvisited directions are never seen: zero columns
    z = w(torch.as_tensor(np.random.default_rng(0).standard_normal((5, 30)))).numpy()
    assert np.isfinite(z).all() and np.all(z[:, 9:] == 0)


@pytest.mark.parametrize("bad, match", [
    (np.ones((50, 8)), "do not vary"),
    (np.full((50, 8), np.nan), "NaN"),
    (np.zeros((1, 8)), "at least 2"),
    (np.zeros((50, 7)), r"shape \(50, 7\); expected \(n, 8\)"),
])
def test_bad_observations_are_refused(bad, match):
    with pytest.raises(ValueError, match=match):
        Whitening(8).fit(bad)


@pytest.mark.parametrize("kw, match", [(dict(rel_floor=0), "rel_floor"), (dict(drop=-1), "drop"),
                                       (dict(drop="x"), "drop"), (dict(rel_floor=float("nan")), "rel_floor"),
                                       (dict(rows_per_component=0.5), "rows_per_component"),
                                       (dict(rows_per_component=True), "rows_per_component"),
                                       (dict(rows_per_component=float("inf")), "rows_per_component")])
def test_bad_settings_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        Whitening(4, **kw)


def test_rows_per_component_keeps_the_leading_directions_the_rows_can_resolve():
    """n = 120 rows of m = 100 components, r = 8: the 15 leading directions keep their gains, the
    others are dropped. With k ≈ n a direction's variance on new data is far above the training
    rows' 1 (Marchenko–Pastur); with the cap it stays near the bound (1 − √(1/8))⁻² ≈ 2.4."""
    y, Q, lam, mu = _gaussian(120, 100, decades=2)
    full, capped = Whitening(100).double().fit(y), Whitening(100, rows_per_component=8).double().fit(y)
    assert capped.info["kept"] == 15 and full.info["kept"] == 100
    assert torch.equal(capped.gain[:15], full.gain[:15]) and torch.all(capped.gain[15:] == 0)
    y_new = torch.as_tensor(mu + (np.random.default_rng(5).standard_normal((4000, 100)) * np.sqrt(lam)) @ Q.T)
    assert full(y_new).var(0).max() > 20 and capped(y_new).var(0)[:15].max() < 2.5


def test_whitening_survives_state_dict_and_checkpoint_resume(tmp_path):
    """The fitted transform is part of the state dict: a fresh network loads it, and a resumed run
    continues bitwise with the same whitening."""
    p = pdeinv.load_problem("heat_1d", n=16, steps=10)
    torch.manual_seed(0)
    model = p.model()
    assert isinstance(model.base, Net) and isinstance(model.base.pre, Whitening)
    fit_preconditioning(model, torch.as_tensor(p.sample(64, 0)[1], dtype=torch.float32))
    fresh = p.model()
    fresh.load_state_dict(model.state_dict())
    assert bool(fresh.base.pre.fitted) and torch.equal(fresh.base.pre.basis, model.base.pre.basis)
    y = torch.as_tensor(p.sample(4, 1)[1], dtype=torch.float32)
    assert torch.equal(fresh(y), model(y))

    def run(steps, resume):
        torch.manual_seed(0)
        tr = pdeinv.Trainer(p, SIP(optimizer=adam(1e-3)), steps=steps, n_train=64, n_test=16,
                            batch_size=16, eval_every=5, checkpoint=Checkpoint(tmp_path / "c.pt", every=5),
                            resume=resume, progress=False, prior=None)
        return tr.fit()

    full = run(10, False)
    (tmp_path / "c.pt").unlink()
    run(5, False)
    resumed = run(10, True)
    for a, b in zip(full.model.state_dict().values(), resumed.model.state_dict().values(), strict=True):
        assert torch.equal(a, b)


def test_whitened_factory_refuses_an_unknown_body():
    with pytest.raises(ValueError, match="body='cnn' is not allowed"):
        whitened("cnn")


def test_marchenko_pastur_median_known_values():
    """μ_1 ≈ 0.6528 (Gavish & Donoho 2014); μ_β → 1 as β → 0."""
    assert abs(marchenko_pastur_median(1.0) - 0.6528) < 1e-4
    assert abs(marchenko_pastur_median(1e-4) - 1.0) < 0.02


@pytest.mark.parametrize("n, m", [(1024, 300), (100, 400), (2000, 60)])
def test_noise_estimate_recovers_the_level_of_low_rank_data(n, m):
    rng = np.random.default_rng(n)
    signal = rng.standard_normal((n, 8)) @ rng.standard_normal((8, m))
    for delta in (0.003, 0.03):
        rms = np.sqrt((signal**2).mean(1, keepdims=True))
        y = signal + delta * rms * rng.standard_normal(signal.shape)
        assert abs(estimate_noise(y) / delta - 1) < 0.1


def test_a_rounding_level_estimate_is_no_noise():
    """Clean float64 observations of heat_1d read 2.5e-16 (rounding): that is no noise level, and
    :func:`estimate_noise` says 0 (noise-free) below ROUNDING_LEVEL; a level just above it, 1e-12, is
    still estimated."""
    import pdeinv
    from pdeinv.inverse.noise import ROUNDING_LEVEL

    _, y = pdeinv.load_problem("heat_1d").sample(300, 5)
    assert estimate_noise(y) == 0.0
    rng = np.random.default_rng(0)
    signal = rng.standard_normal((300, 8)) @ rng.standard_normal((8, 100))
    rms = np.sqrt((signal**2).mean(1, keepdims=True))
    for delta in (1e-12, 1e-6):
        assert delta > ROUNDING_LEVEL
        assert abs(estimate_noise(signal + delta * rms * rng.standard_normal(signal.shape)) / delta - 1) < 0.1


def test_noise_estimate_refuses_bad_input():
    with pytest.raises(ValueError, match="NaN"):
        estimate_noise(np.full((10, 10), np.nan))
    with pytest.raises(ValueError, match="shape"):
        estimate_noise(np.zeros((3, 10)))
