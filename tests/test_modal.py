"""The linear map in the operator's modes (pdeinv.nets.modal, ``--net modal``): what it saves, its
structure, what the rules reach with it against the whitened map, and a run folder's round trip."""

import io

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.nets import linear_default
from pdeinv.nets.defaults import _whitened_fallback
from pdeinv.nets.modal import ModalFeatures, modal, modal_size, visible_modes
from pdeinv.nets.protocol import declared


@pytest.fixture(scope="module")
def boxes():
    return pdeinv.load_problem("heat_boxes", n=16)


def _saved_numbers(model) -> int:
    return sum(v.numel() for v in model.state_dict().values())


def test_only_the_trained_map_and_its_whitening_are_saved(boxes):
    net = modal()(boxes)
    k = visible_modes(boxes)[0].shape[1]
    size = modal_size(boxes)
    assert size["params"] == sum(p.numel() for p in net.parameters()) == k * k + k
    assert _saved_numbers(net) == size["params"] + size["buffers"]  # exact, and no N × k basis in it
    assert not any(boxes.N in v.shape for v in net.state_dict().values())


def test_it_is_linear_in_its_parameters_with_its_modes_as_decoder(boxes):
    net = modal()(boxes)
    lin = declared(net).linear_in_parameters()
    assert lin is not None and lin.decoder is not None  # SIP solves in its span, HIG's Kronecker route
    assert lin.decoder.shape == (visible_modes(boxes)[1].shape[1], boxes.N)
    assert "Kronecker" in pdeinv.plan(boxes, "hig", net="modal").explain()
    assert not isinstance(linear_default(boxes).pre, ModalFeatures)  # n=16: the prior decoder holds them
    nonlinear = pdeinv.load_problem("allen_cahn_1d", n=32)
    assert visible_modes(nonlinear) is None
    with pytest.raises(ValueError, match="spectral basis"):
        modal()(nonlinear)


def test_sip_fits_the_data_with_it_as_well_as_with_the_whitened_map(boxes):
    """Noise-free heat_boxes at n=16, SIP's preset, no prior stage: the modal map fits the data to rounding
    and is about as accurate as the whitened map on the test rows (measured n=32: 0.236 against 0.242; at
    n=64, with 1 024 training rows for 1 103 modes, 0.187 against 0.159), in a file 5× smaller."""
    out = {}
    for name, build in (("modal", modal()), ("whitened", lambda p: _whitened_fallback(p))):
        torch.manual_seed(0)
        r = pdeinv.train(boxes, "sip", model=build(boxes), prior=None, calibration=None, progress=False)
        buffer = io.BytesIO()
        torch.save(r.model.state_dict(), buffer)
        out[name] = (r.metrics["x_err"], r.metrics["y_err"], len(buffer.getvalue()))
    (x_m, y_m, b_m), (x_w, _, b_w) = out["modal"], out["whitened"]
    assert y_m < 1e-7, out
    assert x_m <= 1.02 * x_w, out
    assert b_m * 5 < b_w, out


def test_sip_fits_the_data_on_an_unstructured_mesh():
    """The plate's modes are M-orthonormal, far from orthonormal in ℓ² (cond(ΦᵀΦ) ≈ 9): with them as the
    decoder SIP's 30 steps left the box scene at y-error 4e-3; the span's orthonormal basis makes SIP's
    proxy Hessian the identity and its preset fits the data to rounding."""
    plate = pdeinv.load_problem("heat_plate", prior="boxes", refine=0)
    torch.manual_seed(0)
    r = pdeinv.train(plate, "sip", model=modal()(plate), prior=None, calibration=None, progress=False)
    assert r.metrics["y_err"] < 1e-9, r.metrics
    q = declared(r.model).linear_in_parameters().decoder.double()
    np.testing.assert_allclose(q @ q.T, np.eye(len(q)), atol=1e-10)


def test_a_run_folder_rebuilds_the_same_map(tmp_path):
    from pdeinv.cli import main

    out = tmp_path / "run"
    assert main(["train", "heat_boxes", "--set", "n=12", "--net", "modal", "--steps", "2", "--n-train", "64",
                 "--n-test", "16", "--prior-fit", "0", "--out", str(out), "-q", "--export-samples", "0"]) == 0
    problem, loaded = pdeinv.load_run(out)
    assert isinstance(loaded.pre, ModalFeatures)
    assert (out / "model.pt").stat().st_size < 8 * 3 * problem.N**2  # no N × k basis saved
    _, y = problem.sample(5, seed=4)
    again = pdeinv.load_run(out)[1]
    with torch.no_grad():
        a, b = loaded(torch.as_tensor(y)).numpy(), again(torch.as_tensor(y)).numpy()
    assert np.array_equal(a, b) and np.abs(a).max() > 0


def test_a_saved_run_holds_the_map_folded_with_its_whitening_and_refits(boxes, tmp_path):
    """model.pt holds ``W D Uᵀ`` (k × k) and the mean, not ``W`` and the whitening's k × k basis: half the
    numbers (at heat_boxes 64², k = 1 102: 9.7 MB less), the same predictions; trained again, a folded
    network unfolds as its whitening is refitted (its function kept) and trains as the original does."""
    torch.manual_seed(0)
    r = pdeinv.train(boxes, "sip", model=modal()(boxes), prior=None, calibration=None, progress=False,
                     steps=3)
    k = visible_modes(boxes)[0].shape[1]
    pdeinv.save_run(tmp_path / "r", boxes, {"n": 16}, {"kind": "modal"}, model=r.model)
    saved = torch.load(tmp_path / "r" / "model.pt", weights_only=True)
    assert sum(v.numel() for v in saved.values()) == k * k + 2 * k + 1  # W D Uᵀ, b, μ, the flag
    assert r.model.pre.whitening.basis.shape == (k, k)  # the trained network itself is left as it was
    _, loaded = pdeinv.load_run(tmp_path / "r")
    assert loaded.pre.whitening.folded
    _, y = boxes.sample(6, seed=9)
    with torch.no_grad():
        a, b = r.model(torch.as_tensor(y)).numpy(), loaded(torch.as_tensor(y)).numpy()
    np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12 * np.abs(a).max())
    # trained further, the saved run goes where the trained network itself goes
    ref = pdeinv.train(boxes, "sip", model=r.model, prior=None, calibration=None, progress=False, steps=2)
    again = pdeinv.train(boxes, "sip", model=loaded, prior=None, calibration=None, progress=False, steps=2)
    assert not again.model.pre.whitening.folded
    assert again.metrics["x_err"] == pytest.approx(ref.metrics["x_err"], rel=1e-6)
    # y_err is a residual at 1e-5 of y: the fold's rounding (W D Uᵀ formed once) moves its last digits
    assert again.metrics["y_err"] == pytest.approx(ref.metrics["y_err"], rel=1e-3)
