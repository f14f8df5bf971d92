"""Convergence rates fitted against analytic solutions (scikit-fem test_convergence style).

Space: the time error is made negligible (heat: CN with the modal backend and
10⁵ steps — modal cost does not grow with steps; wave: many Newmark steps), so
the fitted L² rate is the element's, P1 → 2, P2 → 3.
Time: errors against the *semi-discrete* exact solution ``Φ e^{−κTΛ} ΦᵀM x`` on a
fixed mesh isolate the scheme's order, BE → 1, CN → 2, Newmark → 2.
"""

import numpy as np
import pytest
import scipy.linalg as la
from exact import eigenvalue, fitted_rate, l2_error, load, mode

SPACE = {  # (problem, element): (mesh sizes, expected rate)
    ("heat_1d", "P1"): ([8, 16, 32, 64], 2),
    ("heat_1d", "P2"): ([4, 8, 16, 32], 3),
    ("heat_2d", "P1"): ([8, 16, 32], 2),
    ("heat_2d", "P2"): ([4, 8, 16], 3),
}


@pytest.mark.parametrize("name, element", list(SPACE))
def test_heat_space_rate(name, element):
    ns, rate = SPACE[(name, element)]
    kappa, T = 1.0, 0.05
    errs = []
    for n in ns:
        p = load(name, n=n, element=element, kappa=kappa, T=T, steps=100_000,
                 scheme="cn", backend="modal")
        dim = p.points.shape[0]
        y = p.operator.forward(mode(p.points))
        errs.append(l2_error(p.disc, y, np.exp(-kappa * eigenvalue(dim) * T)))
    assert abs(fitted_rate(1.0 / np.array(ns), errs) - rate) < 0.15, errs


# (problem, element): (mesh sizes, expected rate, steps, T). T avoids cos(c√λT) ≈ 0, where only
# the O(h^{2p}) phase error would remain; for 2-D P2 a short T keeps the O(h⁴) phase error
# below the O(h³) interpolation error on these coarse meshes (T=0.3 fits 3.43, T=0.1 fits 2.93).
WAVE_SPACE = {
    ("wave_1d", "P1"): ([8, 16, 32, 64], 2, 400, 0.3),
    ("wave_1d", "P2"): ([4, 8, 16, 32], 3, 4000, 0.3),
    ("wave_2d", "P1"): ([8, 16, 32], 2, 400, 0.3),
    ("wave_2d", "P2"): ([4, 8, 16], 3, 1000, 0.1),
}


@pytest.mark.parametrize("element, ns, rate", [("P1", [8, 16, 32], 2), ("P2", [4, 8, 16], 3)])
def test_advection_diffusion_space_rate(element, ns, rate):
    """The cellular flow does not advect its own stream function ``sin πx sin πy``
    (``w·∇u₀ = 0``), so ``u(T) = e^{−2π²κT} u₀`` at any speed: a test of the convection
    matrix's consistency (streamline diffusion is off here: ``h < 2κ/|w|``)."""
    kappa, T = 0.1, 0.1
    errs = []
    for n in ns:
        p = load("advection_diffusion_2d", n=n, element=element, kappa=kappa, T=T, speed=1.0,
                 steps=2000, scheme="cn", backend="steps")  # one forward: no compiled build
        y = p.operator.forward(mode(p.points))
        errs.append(l2_error(p.disc, y, np.exp(-kappa * eigenvalue(2) * T)))
    assert abs(fitted_rate(1.0 / np.array(ns), errs) - rate) < 0.2, errs


@pytest.mark.parametrize("name, element", list(WAVE_SPACE))
def test_wave_space_rate(name, element):
    ns, rate, steps, T = WAVE_SPACE[(name, element)]
    c = 1.0
    errs = []
    for n in ns:
        p = load(name, n=n, element=element, c=c, T=T, steps=steps, backend="steps")  # one forward
        dim = p.points.shape[0]
        y = p.operator.forward(mode(p.points))
        errs.append(l2_error(p.disc, y, np.cos(c * np.sqrt(eigenvalue(dim)) * T)))
    assert abs(fitted_rate(1.0 / np.array(ns), errs) - rate) < 0.2, errs


@pytest.mark.parametrize("scheme, rate", [("be", 1), ("cn", 2)])
def test_heat_time_rate(scheme, rate):
    kappa, T = 1.0, 0.1
    base = load("heat_1d", n=32, kappa=kappa, T=T)
    M, K = base.disc.M.toarray(), base.disc.K.toarray()
    lam, Phi = la.eigh(K, M)
    x = mode(base.points)
    semi = Phi @ (np.exp(-kappa * T * lam) * (Phi.T @ M @ x))
    steps = np.array([10, 20, 40, 80])
    errs = []
    for s in steps:
        y = load("heat_1d", n=32, kappa=kappa, T=T, steps=int(s), scheme=scheme,
                 backend="steps").operator.forward(x)
        errs.append(base.disc.norm(y - semi)[0])
    assert abs(fitted_rate(T / steps, errs) - rate) < 0.1, errs


def test_wave_time_rate():
    c, T = 1.0, 0.5
    base = load("wave_1d", n=32, c=c, T=T)
    M, K = base.disc.M.toarray(), base.disc.K.toarray()
    lam, Phi = la.eigh(K, M)
    x = mode(base.points)
    semi = Phi @ (np.cos(c * np.sqrt(lam) * T) * (Phi.T @ M @ x))
    steps = np.array([10, 20, 40, 80])
    errs = [base.disc.norm(load("wave_1d", n=32, c=c, T=T, steps=int(s)).operator.forward(x)
                           - semi)[0] for s in steps]
    assert abs(fitted_rate(T / steps, errs) - 2) < 0.1, errs
