"""HIG's last-layer route for dense networks not linear in θ (MLPs): the exact step of the last layer.

For ``x_i = D(W_L h̃_i)`` with ``h_i = σ(… σ(W_1 h_0(y_i)) …)`` (an ``nn.Sequential`` of ``nn.Linear``
and elementwise activations behind a fixed input map ``h_0`` and before a fixed linear output map
``D``: :class:`pdeinv.MLP`, :func:`pdeinv.nets.dense`, or a :class:`~pdeinv.nets.Net` with such a
body), ``W̃_L = [W_L b_L]`` and ``h̃_i = [h_i; 1]``, sample i's Jacobian of ``y_i = P x_i`` is, per
layer, ``J_{i,ℓ} = P D (∂f_i/∂a_{i,ℓ}) ⊗ h̃_{i,ℓ−1}ᵀ`` (``a``: the layer's pre-activation). For the
last layer ``∂f_i/∂a_{i,L} = I`` for every sample, so its block of ``JᵀJ`` is exactly Kronecker,

    J_LᵀJ_L = (P̂ᵀP̂) ⊗ (H̃ᵀH̃),   P̂ = P D,

which is :mod:`.hig_kron`'s algebra with the hidden features ``H̃`` as ``Z̃``: the network is linear
in ``W̃_L`` after the fixed feature map of its hidden layers. This route takes that exact step
(:func:`.hig_kron.direction_rows`, or :func:`.hig_kron.direction` when the batch has at least as many
rows as ``H̃`` has columns): one ``B × B`` eigendecomposition, the SVD of ``P̂`` once per run
(:func:`pdeinv.inverse.decoder.decoded_svd`), no Jacobian, no extra physics call.

**What is approximated.** ``JᵀJ`` is replaced by its last-layer block: the hidden layers' blocks and
all cross terms are dropped, so **the hidden layers take no step** (they keep their initialization:
a random-feature network whose readout is trained by HIG's exact step). ``τ``, ``σ_max`` and
``normalize`` are those of ``J_L`` (``info["sigma_max"]``). A network with one ``nn.Linear`` (or with
its hidden layers frozen) therefore gets exactly :class:`~.hig.HIG`'s step (``tests/test_hig_layers.py``).

**Why not the hidden layers too.** A Kronecker-factored block per hidden layer,
``J_ℓᵀJ_ℓ ≈ Ḡ_ℓ ⊗ A_ℓ`` (K-FAC, Martens & Grosse 2015: ``A_ℓ = H̃ᵀH̃``, ``Ḡ_ℓ`` the exact batch mean of
``E_iᵀE_i``, ``E_i = diag(s)Vᵀ ∂f_i/∂a_{i,ℓ}``), with the step
``ΔW̃_ℓ = −η Q_G [(Q_Gᵀ ∇_ℓ Q_A) ⊙ σ^(e−1)] Q_Aᵀ``, is exact only for a batch of one: otherwise the
factorization spans directions ``J_ℓ`` does not have (``E_i`` of one sample with ``h̃_j`` of another) with
small ``σ``, which ``σ^(e−1) = σ^-3/2`` amplifies, and the training diverges.

Hence ``auto`` (:data:`.hig_routes.ROUTES`): where the dense ``J`` fits, HIG's exact step (it trains
every layer); where it does not, this route, 100–500× faster per step than the matrix-free route and more
accurate at equal wall time (``benchmarks/hig_mlp.py``; benchmarks/notes/scaling.md). A narrow MLP's
random features limit it (``tests/test_hig_layers.py``).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ...inverse.decoder import DecodedSVD
from . import kron as hig_kron

#: the elementwise activations a supported body may hold between its ``nn.Linear`` layers
ELEMENTWISE = (nn.Tanh, nn.ReLU, nn.Sigmoid, nn.GELU, nn.SiLU, nn.Softplus, nn.ELU, nn.LeakyReLU,
               nn.Identity)

SUPPORTED = ("pdeinv.MLP, pdeinv.nets.dense (an nn.Sequential of nn.Linear layers and elementwise "
             f"activations ({', '.join(c.__name__ for c in ELEMENTWISE)}) ending in nn.Linear), or a "
             "pdeinv.nets.Net with such a body")


def body(model: nn.Module, route: str = "last_layer") -> tuple:
    """``(before, mods, decoder)``: the fixed input map (``None``: the identity), the body's modules
    (``nn.Linear`` and :data:`ELEMENTWISE` activations, ending in an ``nn.Linear``) and the decoder rows
    ``Dᵀ`` (``None``: the identity) of a supported network; ``ValueError`` naming what ``route``
    supports for any other."""
    from ...nets import MLP, Net

    decoder = None
    if isinstance(model, MLP):
        net, before = model.body, lambda y: (y - model.shift) / model.scale  # noqa: E731
    elif isinstance(model, Net):
        if not isinstance(model.post, nn.Identity) and model.decoder is None:
            _refuse(model, route, f"its output map {type(model.post).__name__} is not a fixed decoder")
        net, before, decoder = model.body, model.pre, model.decoder
    elif isinstance(model, nn.Sequential):
        net, before = model, None
    else:
        _refuse(model, route, "it is none of them")
    if not isinstance(net, nn.Sequential | nn.Linear):
        _refuse(model, route, f"its body is a {type(net).__name__}")
    mods = list(net) if isinstance(net, nn.Sequential) else [net]
    if not mods or type(mods[-1]) is not nn.Linear:
        _refuse(model, route, "its body does not end in an nn.Linear")
    odd = [type(m).__name__ for m in mods if type(m) is not nn.Linear and not isinstance(m, ELEMENTWISE)]
    if odd:
        _refuse(model, route, f"its body holds {', '.join(odd)}")
    return before, mods, decoder


def names(model: nn.Module, layer: nn.Linear) -> tuple:
    """The model's names of ``layer``'s (weight, bias)."""
    names_of = {id(p): n for n, p in model.named_parameters()}
    return tuple(names_of[id(p)] for p in (layer.weight, layer.bias) if p is not None)


def last_layer(model: nn.Module):
    """``(lin, names)``: ``model`` as linear in its last layer after the fixed map of the others
    (:class:`pdeinv.nets.LinearInParameters`: features, decoder rows ``Dᵀ`` or ``None``, the last
    ``nn.Linear``) and the model's names of that layer's (weight, bias); ``ValueError`` naming what is
    supported for any other network (:func:`body`), or when the last layer is frozen."""
    from ...nets import LinearInParameters

    before, mods, decoder = body(model)
    layer = mods[-1]
    if not all(p.requires_grad for p in layer.parameters()):
        raise ValueError("HIG(route='last_layer') steps the last nn.Linear layer only; it is (partly) frozen "
                         "here: unfreeze its weight and bias, or use route='svd'")
    hidden = nn.Sequential(*mods[:-1])
    features = hidden if before is None else (lambda y: hidden(before(y)))  # noqa: E731
    return LinearInParameters(features, decoder, layer), names(model, layer)


def _refuse(model, route: str, why: str):
    raise ValueError(f"HIG(route={route!r}) supports {SUPPORTED}; {type(model).__name__} is not "
                     f"supported: {why}")


def direction(lin, names: tuple, fac: DecodedSVD, y: torch.Tensor, R: np.ndarray, eta: float, tau: float,
              exponent: float) -> tuple[dict, dict]:
    """``{parameter name: ΔW̃ part}`` for the last layer (unnormalized: :class:`~.hig.HIG` multiplies by
    ``σ_max^-(1+e)``) and what was kept, from the observations ``y`` and the residuals ``R`` (``B × m``,
    float64, in ``fac``'s output coordinates): :mod:`.hig_kron`'s exact step on the hidden features."""
    _, Z = hig_kron.forward(lin, y)
    if len(Z) < Z.shape[1]:
        delta, info = hig_kron.direction_rows(fac, Z, R, eta, tau, exponent)
    else:
        G, N = hig_kron.moments(fac, Z, R)
        delta, info = hig_kron.direction(fac, G, N, len(Z), eta, tau, exponent)
    parts = {names[0]: delta[:, : lin.layer.in_features]}
    if lin.layer.bias is not None:
        parts[names[1]] = delta[:, -1]
    steps = {n: torch.from_numpy(np.ascontiguousarray(v)) for n, v in parts.items()}
    return steps, {**info, "route": "last_layer"}
