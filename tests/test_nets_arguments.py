"""Bad arguments to pdeinv.nets' public constructors and factories: a ``ValueError`` (wrong value) or
``TypeError`` (wrong kind) in one line that names the argument, raised when the network or factory is
made (not at its first use); and valid arguments (numpy integers as sizes included) still build and run."""

import numpy as np
import pytest
import torch
from torch import nn

import pdeinv
from pdeinv import nets
from pdeinv.fem.grid import GridMap, spacing
from pdeinv.nets.unet import inputs, size


@pytest.fixture(scope="module")
def p8():
    return pdeinv.load_problem("heat_1d", n=8)


@pytest.fixture(scope="module")
def grid(p8):
    return GridMap(p8.points, spacing(p8.disc.basis.mesh))


@pytest.fixture(scope="module")
def net(p8):
    return nets.linear_default(p8)


_PROBLEM = r"^problem=None is NoneType, not a pdeinv\.Problem"
_INT1 = "is not allowed; expected an integer >= 1$"
_DTYPE = (r"expected a floating-point dtype: torch\.float16, torch\.bfloat16, torch\.float32 or "
          r"torch\.float64$")

# (id, call(ctx) with ctx = {"p8", "grid", "net"}, exception type, message regex)
CASES = [
    # --- the fuzz round's cases ---------------------------------------------------------------------
    ("linear_default-None", lambda c: nets.linear_default(None), TypeError, _PROBLEM),
    ("default_model-None", lambda c: nets.default_model(None), TypeError, _PROBLEM),
    ("MeshUNet-grid-int", lambda c: nets.MeshUNet(5, None, True), TypeError,
     r"^grid=5 is int; expected a pdeinv\.fem\.grid\.GridMap"),
    ("MeshUNet-grid-None-channels-0", lambda c: nets.MeshUNet(None, None, True, channels=0), TypeError,
     r"^grid=None is NoneType; expected a pdeinv\.fem\.grid\.GridMap"),
    ("MLP-n_in-negative", lambda c: nets.MLP(-1, 7), ValueError, "^n_in=-1 " + _INT1),
    ("MLP-hidden-negative", lambda c: nets.MLP(7, 7, hidden=(-1,)), ValueError,
     r"^hidden=\(-1,\) is not allowed; expected integer widths >= 1"),
    ("ModalFeatures-1d", lambda c: nets.ModalFeatures(np.zeros(3)), ValueError,
     r"^proj has shape \(3,\); expected a 2-D \(m, k\) array with m, k >= 1$"),
    ("MLP-n_in-str", lambda c: nets.MLP("7", 7), ValueError, "^n_in='7' " + _INT1),
    ("MLP-n_in-float", lambda c: nets.MLP(7.0, 7), ValueError, "^n_in=7.0 " + _INT1),
    ("MLP-hidden-str", lambda c: nets.MLP(7, 7, hidden="64,64"), TypeError,
     r"^hidden='64,64' is str; expected a tuple of integer widths"),
    ("MLP-hidden-int", lambda c: nets.MLP(7, 7, hidden=8), TypeError,
     r"^hidden=8 is int; expected a tuple of integer widths"),
    ("MLP-activation-int", lambda c: nets.MLP(7, 7, activation=5), TypeError,
     r"^activation=5 is not allowed; expected a torch\.nn\.Module class"),
    ("whitened-dtype-int32", lambda c: nets.whitened(dtype=torch.int32), ValueError,
     r"^dtype=torch\.int32 is not allowed; " + _DTYPE),
    ("ModalFeatures-str", lambda c: nets.ModalFeatures("abc"), TypeError,
     r"^proj='abc' is str of dtype <U3; expected a real \(m, k\) array$"),
    ("MLP-n_in-zero", lambda c: nets.MLP(0, 7), ValueError, "^n_in=0 " + _INT1),
    ("MLP-n_out-zero", lambda c: nets.MLP(7, 0), ValueError, "^n_out=0 " + _INT1),
    ("default_model-refine-str", lambda c: nets.default_model(c["p8"], refine="no"), TypeError,
     r"^refine='no' is str; expected True or False$"),
    ("ModalFeatures-nan", lambda c: nets.ModalFeatures(np.full((7, 3), np.nan)), ValueError,
     r"^proj contains NaN or Inf \(first at index \(0, 0\)\); expected finite values$"),
    # --- mlp.py ---------------------------------------------------------------------------------------
    ("MLP-n_in-bool", lambda c: nets.MLP(True, 7), ValueError, "^n_in=True " + _INT1),
    ("MLP-hidden-zero-width", lambda c: nets.MLP(7, 7, hidden=(8, 0)), ValueError, r"^hidden=\(8, 0\)"),
    ("MLP-activation-instance", lambda c: nets.MLP(7, 7, activation=nn.Tanh()), TypeError,
     r"^activation=Tanh\(\) is not allowed; expected a torch\.nn\.Module class"),
    ("dense-n_out-negative", lambda c: nets.dense(7, -2), ValueError, "^n_out=-2 " + _INT1),
    ("Residual-n_in-zero", lambda c: nets.Residual(0, 7), ValueError, "^n_in=0 " + _INT1),
    ("Residual-hidden-str", lambda c: nets.Residual(7, 7, hidden="8"), TypeError, r"^hidden='8' is str"),
    ("zero_last_layer-int", lambda c: nets.zero_last_layer(5), TypeError,
     r"^model=5 is int; expected a torch\.nn\.Module$"),
    ("mlp-factory-None", lambda c: nets.mlp((8,))(None), TypeError, _PROBLEM),
    # --- net.py ---------------------------------------------------------------------------------------
    ("whitened-dtype-str", lambda c: nets.whitened(dtype="float64"), TypeError,
     r"^dtype='float64' is str; expected a torch dtype: torch\.float16"),
    ("whitened-dtype-complex", lambda c: nets.whitened(dtype=torch.complex128), ValueError,
     r"^dtype=torch\.complex128 is not allowed"),
    ("whitened-body", lambda c: nets.whitened("cnn"), ValueError,
     r"^body='cnn' is not allowed; expected one of 'linear', 'mlp', 'residual'$"),
    ("whitened-body-list", lambda c: nets.whitened(["mlp"]), ValueError, r"^body=\['mlp'\] is not allowed"),
    ("whitened-hidden-int", lambda c: nets.whitened("mlp", hidden=8), TypeError, r"^hidden=8 is int"),
    ("whitened-activation", lambda c: nets.whitened("mlp", activation="tanh"), TypeError,
     r"^activation='tanh' is not allowed"),
    ("whitened-components", lambda c: nets.whitened(components=0), ValueError,
     r"^components=0 is not allowed; expected an integer >= 1 or None$"),
    ("whitened-rows_per_component", lambda c: nets.whitened(rows_per_component=0.5), ValueError,
     r"^rows_per_component=0\.5 is not allowed; expected a number >= 1 or None$"),
    ("whitened-rel_floor", lambda c: nets.whitened(rel_floor=-1.0), ValueError, r"^rel_floor=-1\.0 is not"),
    ("whitened-drop", lambda c: nets.whitened(drop="none"), ValueError,
     r"^drop='none' is not allowed; expected 'edge' or a number >= 0$"),
    ("whitened-factory-None", lambda c: nets.whitened()(None), TypeError, _PROBLEM),
    ("Net-pre-int", lambda c: nets.Net(5, nn.Linear(2, 2)), TypeError,
     r"^pre=5 is int; expected a torch\.nn\.Module$"),
    ("Net-post-str", lambda c: nets.Net(nn.Identity(), nn.Identity(), "x"), TypeError,
     r"^post='x' is str; expected a torch\.nn\.Module or None$"),
    ("fit_preconditioning-None", lambda c: nets.fit_preconditioning(None, np.zeros((4, 7))), TypeError,
     r"^model=None is NoneType; expected a torch\.nn\.Module$"),
    # --- reduced.py -----------------------------------------------------------------------------------
    ("reduced-k_in-zero", lambda c: nets.reduced(k_in=0), ValueError, "^k_in=0 " + _INT1),
    ("reduced-k_out-float", lambda c: nets.reduced(k_out=2.5), ValueError, "^k_out=2.5 " + _INT1),
    ("reduced-k_in-numpy-zero", lambda c: nets.reduced(k_in=np.int64(0)), ValueError,
     r"^k_in=\S*0\)? is not"),
    ("reduced-k_max-str", lambda c: nets.reduced(k_max="8"), ValueError, "^k_max='8' " + _INT1),
    ("reduced-dtype", lambda c: nets.reduced(dtype=torch.int64), ValueError, r"^dtype=torch\.int64 is not"),
    ("reduced-hidden", lambda c: nets.reduced(body="mlp", hidden=(0,)), ValueError, r"^hidden=\(0,\)"),
    ("reduced-activation", lambda c: nets.reduced(activation=None), TypeError, r"^activation=None is not"),
    ("reduced-scaled", lambda c: nets.reduced(scaled="yes"), TypeError,
     r"^scaled='yes' is str; expected True or False$"),
    ("reduced-samples", lambda c: nets.reduced(samples=0), ValueError, "^samples=0 " + _INT1),
    ("reduced-uncaptured", lambda c: nets.reduced(uncaptured=-1e-3), ValueError,
     r"^uncaptured=-0\.001 is not allowed; expected a number >= 0$"),
    ("reduced-at_most", lambda c: nets.reduced(at_most=float("nan")), ValueError,
     r"^at_most=nan is not allowed; expected a finite number >= 0$"),
    ("reduced-rows_per_component", lambda c: nets.reduced(rows_per_component=0), ValueError,
     r"^rows_per_component=0 is not allowed"),
    ("reduced-drop", lambda c: nets.reduced(drop=True), ValueError, r"^drop=True is not allowed"),
    ("reduced-factory-None", lambda c: nets.reduced()(None), TypeError, _PROBLEM),
    ("Decoder-str", lambda c: nets.Decoder("abc"), TypeError, r"^basis='abc' is str of dtype <U3; expected"),
    ("Decoder-None", lambda c: nets.Decoder(None), TypeError, r"^basis=None is NoneType; expected a real"),
    ("Decoder-1d", lambda c: nets.Decoder(np.zeros(3)), ValueError, r"^basis has shape \(3,\); expected"),
    ("Decoder-empty", lambda c: nets.Decoder(np.zeros((3, 0))), ValueError, r"^basis has shape \(3, 0\)"),
    ("Decoder-inf-tensor", lambda c: nets.Decoder(torch.tensor([[1.0, float("inf")]])), ValueError,
     r"^basis contains NaN or Inf \(first at index \(0, 1\)\)"),
    ("Decoder-persistent", lambda c: nets.Decoder(np.eye(3), persistent="no"), TypeError,
     r"^persistent='no' is str; expected True or False$"),
    ("prior_basis-None", lambda c: nets.prior_basis(None, 4), TypeError, _PROBLEM),
    ("prior_basis-k", lambda c: nets.prior_basis(c["p8"], 0), ValueError, "^k=0 " + _INT1),
    ("prior_basis-seed", lambda c: nets.prior_basis(c["p8"], 4, seed=-1), ValueError,
     r"^seed=-1 is not allowed; expected an integer from 0 to"),
    ("prior_basis-chunk", lambda c: nets.prior_basis(c["p8"], 4, chunk=0), ValueError, "^chunk=0 " + _INT1),
    ("prior_basis-scaled", lambda c: nets.prior_basis(c["p8"], 4, scaled=1), TypeError,
     r"^scaled=1 is int; expected True or False$"),
    ("decoder_basis-None", lambda c: nets.decoder_basis(None), TypeError, _PROBLEM),
    ("decoder_basis-k", lambda c: nets.decoder_basis(c["p8"], k=-3), ValueError, "^k=-3 " + _INT1),
    ("decoder_basis-k_max", lambda c: nets.decoder_basis(c["p8"], k_max=0), ValueError, "^k_max=0 " + _INT1),
    ("decoder_basis-at_most", lambda c: nets.decoder_basis(c["p8"], at_most=-1), ValueError, r"^at_most=-1"),
    # --- modal.py -------------------------------------------------------------------------------------
    ("modal-dtype", lambda c: nets.modal(dtype=torch.int32), ValueError, r"^dtype=torch\.int32 is not"),
    ("modal-rows_per_component", lambda c: nets.modal(rows_per_component=float("inf")), ValueError,
     r"^rows_per_component=inf is not allowed"),
    ("modal-factory-None", lambda c: nets.modal()(None), TypeError, _PROBLEM),
    ("ModalFeatures-None", lambda c: nets.ModalFeatures(None), TypeError,
     r"^proj=None is NoneType; expected a real \(m, k\) array$"),
    ("ModalFeatures-complex", lambda c: nets.ModalFeatures(np.ones((3, 2), complex)), TypeError,
     r"^proj=array\(\[\[1\.\+0\.j, .* is ndarray of dtype complex128; expected a real \(m, k\) array$"),
    ("ModalFeatures-rows_per_component", lambda c: nets.ModalFeatures(np.eye(3), rows_per_component=0),
     ValueError, r"^rows_per_component=0 is not allowed"),
    # --- unet.py --------------------------------------------------------------------------------------
    ("MeshUNet-channels-0", lambda c: nets.MeshUNet(c["grid"], None, True, channels=0), ValueError,
     "^channels=0 " + _INT1),
    ("MeshUNet-channels-float", lambda c: nets.MeshUNet(c["grid"], None, True, channels=2.5), ValueError,
     "^channels=2.5 " + _INT1),
    ("MeshUNet-observed-str", lambda c: nets.MeshUNet(c["grid"], None, "yes"), TypeError,
     r"^observed='yes' is str; expected True or False$"),
    ("MeshUNet-residual-int", lambda c: nets.MeshUNet(c["grid"], None, True, residual=1), TypeError,
     r"^residual=1 is int; expected True or False$"),
    ("MeshUNet-physics-int", lambda c: nets.MeshUNet(c["grid"], 5, True), TypeError,
     r"^physics=5 is int; expected a pdeinv\.nets\.corrections\.SpectralFilter"),
    ("unet-channels", lambda c: nets.unet(channels=0), ValueError, "^channels=0 " + _INT1),
    ("unet-residual", lambda c: nets.unet(residual="no"), TypeError, r"^residual='no' is str"),
    ("unet-refine", lambda c: nets.unet(refine=None), TypeError, r"^refine=None is NoneType"),
    ("unet-factory-None", lambda c: nets.unet()(None), TypeError, _PROBLEM),
    ("unet-size-None", lambda c: size(None), TypeError, _PROBLEM),
    ("unet-inputs-None", lambda c: inputs(None), TypeError, _PROBLEM),
    # --- defaults.py ----------------------------------------------------------------------------------
    ("default_model-str", lambda c: nets.default_model("heat_1d"), TypeError,
     r"^problem='heat_1d' is str, not a pdeinv\.Problem; load it with"),
    ("default_model-base", lambda c: nets.default_model(c["p8"], base="linear"), ValueError,
     r"^base='linear' is not allowed; expected 'auto' or 'whitened'$"),
    ("default_model-correction", lambda c: nets.default_model(c["p8"], correction="cnn"), ValueError,
     r"^correction='cnn' is not allowed; expected 'auto', 'grid', 'dense' or 'span'$"),
    ("default_model-rows_per_component", lambda c: nets.default_model(c["p8"], rows_per_component=-1),
     ValueError, r"^rows_per_component=-1 is not allowed"),
    ("linear_default-rows_per_component", lambda c: nets.linear_default(c["p8"], rows_per_component="8"),
     ValueError, r"^rows_per_component='8' is not allowed"),
    ("linear_default-path", lambda c: nets.linear_default(np.zeros(3)), TypeError,
     r"^problem=array\(.*is ndarray, not a pdeinv\.Problem"),
    ("refined-None", lambda c: nets.refined(None, c["net"]), TypeError, _PROBLEM),
    ("refined-base", lambda c: nets.refined(c["p8"], None), TypeError,
     r"^base=None is NoneType; expected a torch\.nn\.Module"),
    ("refined-correction", lambda c: nets.refined(c["p8"], c["net"], correction=None), ValueError,
     r"^correction=None is not allowed"),
    ("correction_kind-None", lambda c: nets.correction_kind(None), TypeError, _PROBLEM),
    ("data_base-None", lambda c: nets.data_base(None), TypeError, _PROBLEM),
    ("default_size-None", lambda c: nets.default_size(None), TypeError, _PROBLEM),
    ("refined_size-None", lambda c: nets.refined_size(None), TypeError, _PROBLEM),
    ("network_size-None", lambda c: nets.network_size(None), TypeError, _PROBLEM),
    ("network_size-hidden", lambda c: nets.network_size(c["p8"], "mlp", hidden=(0,)), ValueError,
     r"^hidden=\(0,\) is not allowed"),
    ("network_size-hidden-str", lambda c: nets.network_size(c["p8"], "mlp", hidden="64"), TypeError,
     r"^hidden='64' is str"),
    ("network_size-kind", lambda c: nets.network_size(c["p8"], 5), ValueError, r"^kind=5 is not allowed"),
    ("network_size-rows_per_component", lambda c: nets.network_size(c["p8"], rows_per_component=0),
     ValueError, r"^rows_per_component=0 is not allowed"),
]


@pytest.mark.parametrize("call, kind, match", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_arguments_are_refused_in_one_line_naming_them(p8, grid, net, call, kind, match):
    with pytest.raises(kind, match=match) as info:
        call({"p8": p8, "grid": grid, "net": net})
    assert info.type is kind  # not a subclass raised from deeper inside
    assert "\n" not in str(info.value)


def _y(problem, n=16):
    return torch.as_tensor(problem.sample(n, seed=0)[1])


def test_valid_arguments_numpy_integers_included_still_build_and_run(p8, grid):
    y = _y(p8)
    m, n = p8.operator.n_out, p8.operator.n_in
    built = {
        "MLP": nets.MLP(np.int64(m), np.int32(n), hidden=[np.int64(8), 4], activation=nn.GELU),
        "MLP-no-hidden": nets.MLP(m, n, hidden=()),  # (): one linear layer
        "mlp": nets.mlp((np.int64(8),))(p8),
        "whitened": nets.whitened("mlp", hidden=(8,), components=np.int64(3), dtype=torch.float32,
                                  rows_per_component=np.float64(2.0), drop=np.float64(0.0))(p8),
        "whitened-residual": nets.whitened("residual", hidden=(), rel_floor=1e-8)(p8),
        "reduced": nets.reduced(k_in=np.int64(4), k_out=np.int32(4), k_max=np.int64(8), samples=np.int64(32),
                                at_most=1.0)(p8),
        "modal": nets.modal(rows_per_component=8)(p8),
        "modal-features": nets.Net(nets.ModalFeatures(np.eye(m, 3).astype(np.float32)),
                                   nets.dense(3, n, ())).double(),
        "linear_default": nets.linear_default(p8),
        "default_model": nets.default_model(p8),
        "default_model-bare": nets.default_model(p8, refine=False, base="whitened"),
        "refined": nets.refined(p8, nets.linear_default(p8), correction="dense"),
        "unet": nets.unet(channels=np.int64(4), refine=False)(p8),
        "unet-refined": nets.unet(channels=4, residual=True)(p8),
        "MeshUNet": nets.MeshUNet(grid, None, True, channels=np.int64(2)),
        "Net-decoder": nets.Net(nn.Identity(), nets.dense(m, 3, ()), nets.Decoder(torch.eye(n, 3))),
    }
    for name, model in built.items():
        nets.fit_preconditioning(model, y)
        x = model(y.to(next(model.parameters()).dtype))
        assert x.shape == (len(y), n), name
        assert torch.isfinite(x).all(), name
    assert nets.Decoder(torch.eye(n, 3, dtype=torch.float32)).basis.dtype == torch.float32  # kept
    assert nets.Decoder(np.eye(n, 3, dtype=np.int64)).basis.dtype == torch.float64
    assert nets.Residual(np.int64(m), n, (4,))(y.float()).shape == (len(y), n)
    assert nets.zero_last_layer(nn.Sequential(nn.Linear(2, 3))) is not None
    basis, _ = nets.prior_basis(p8, np.int64(3), samples=16, seed=np.int64(1), chunk=np.int32(8))
    assert basis.shape == (n, 3)
    assert nets.decoder_basis(p8, k=np.int64(3), k_max=np.int64(4))[0].shape[0] == n
    assert nets.network_size(p8, "default")["params"] > 0
    assert nets.network_size(p8, "mlp", hidden=[np.int64(8)])["params"] > 0
    assert nets.network_size(p8, "linear", hidden=())["params"] > 0  # (): no MLP, the kind decides
    assert nets.default_size(p8)[0] > 0 and nets.refined_size(p8) >= 0
    assert nets.correction_kind(p8) == "dense" and nets.data_base(p8) == "whitened"
    assert size(p8, channels=np.int64(4))["params"] > 0 and inputs(p8) >= 1
