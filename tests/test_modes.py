"""The large-mesh eigen build: one eigsh call sized by Weyl's law, the same modes as a dense eigh."""

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse.linalg as sla

import pdeinv
from pdeinv.errors import TooManyModes
from pdeinv.physics import Heat, Modal, modes


def _heat(n, **kw):
    d = pdeinv.discretize(pdeinv.mesh.unit_square(n))
    return Heat(d.M, d.K, backend="steps", measure=d.measure, dim=d.dim, **kw)


@pytest.mark.parametrize("scheme", ["be", "cn"])
def test_one_eigsh_call_gives_the_dense_modes(monkeypatch, scheme):
    """~120 of 529 modes kept: the former start at 64 took 2 calls."""
    heat = _heat(24, scheme=scheme, kappa=0.02)
    monkeypatch.setenv("PDEINV_NO_CACHE", "1")  # compute both
    dense = Modal(heat)
    calls = []
    real = sla.eigsh

    def counted(*a, **k):
        if "sigma" in k:  # shift-invert calls for the lowest modes (CN also asks for λ_max)
            calls.append(a[1])
        return real(*a, **k)

    monkeypatch.setattr(modes, "DENSE_MAX", 10)
    monkeypatch.setattr(modes.sla, "eigsh", counted)
    sparse = Modal(heat)
    assert len(calls) == 1 and calls[0] < heat.n_in / 2, calls
    assert sparse.k == dense.k > 64  # exactly the same set of modes kept
    assert np.max(np.abs(sparse.lam - dense.lam) / dense.lam) <= 1e-10
    x = np.random.default_rng(0).standard_normal((3, heat.n_in))
    yd = dense.forward(x)
    assert np.linalg.norm(sparse.forward(x) - yd) / np.linalg.norm(yd) <= 1e-10


def test_a_low_guess_takes_one_more_call_and_too_many_modes_is_refused(monkeypatch):
    d = pdeinv.discretize(pdeinv.mesh.unit_square(16))
    monkeypatch.setattr(modes, "DENSE_MAX", 10)
    full = scipy.linalg.eigh(d.K.toarray(), d.M.toarray(), eigvals_only=True)
    lam, Phi = modes.lowest_modes(d.M, d.K, lambda lam: lam[-1] > full[40], k=30)
    assert len(lam) == 60 and np.allclose(lam, full[:60], rtol=1e-10)
    with pytest.raises(TooManyModes, match="more than"):
        modes.lowest_modes(d.M, d.K, lambda lam: False, k=30)
    with pytest.raises(ValueError, match="k=0"):
        modes.lowest_modes(d.M, d.K, lambda lam: True, k=0)
