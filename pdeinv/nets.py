"""Default networks ``f(y; θ) ≈ x``, and how they were chosen.

Every head starts at zero: a random head emits components the physics cannot see
(its null space), and no update rule removes them again (x-error near 1.0 against
0.2–0.3 with a zero head on a 961-unknown heat problem).

Three kinds of network:

* :class:`Net` = a fitted input transform (:class:`~pdeinv.precondition.Whitening`,
  PCA whitening of the training observations) and a body from :data:`BODIES`:
  ``linear`` (``x = A z + b``), ``mlp`` (tanh layers), ``residual`` (both, summed);
  built by :func:`whitened`, in float64 (:data:`DTYPE`). The **default** where the operator is
  reversible (the wave scenes, :func:`default_model`) up to :data:`REDUCED_ABOVE` unknowns or
  observations. It has ``min(m, N)·N + N`` parameters and an ``N × N`` whitening (heat_2d
  at n = 128: 260 M parameters), so above that, and on every other scene:
* :func:`reduced`: the same :class:`Net` on the ``k_in`` leading whitened components,
  with a fixed decoder basis ``Φ`` (:class:`Decoder`, the prior's principal components) on the
  output: ``x = Φ body(z)``; its trained size does not depend on the mesh, and the prior fills
  what the observations do not see.
* :class:`MLP`: a tanh MLP (256, 256) on per-node standardized input, what ``--method adam``
  trains (:mod:`pdeinv.methods.presets` says why: a first-order rule leaves weight on the
  trailing whitened directions, which new data amplify).

Both default networks are linear in their parameters after a fixed feature map
(:meth:`Net.linear_in_parameters`): SIP's proxy step is then a Newton step
(:meth:`Net.gauss_newton_diagonal`) and HIG has an exact Kronecker-factored step
(:mod:`pdeinv.methods.hig_kron`). Measured against best-α Tikhonov on every scene with
``benchmarks/accuracy.py``: the table is in ``docs/results.md``. The whitening is fitted by
the trainer on the training observations only (:func:`fit_preconditioning`), never on ``x``,
and travels with the state dict.

History: an earlier sweep (SIP with Adam on the proxy, float32, 20 s per run) picked the
whitened linear map for heat (0.032 on heat_2d against 0.073 for the whitened MLP and 0.191
for the standardized MLP) and kept the MLP for the wave scenes, where time reversal made SIP
a gradient step; with the spectral local inverse and the curvature-normalized proxy step the
linear map wins there too (SIP on wave_2d: 5e-9, 1000× below the 0.2–0.3 of the MLP runs).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch
from torch import nn

from .precondition import Whitening


class MLP(nn.Module):
    """``x = W_L σ(… σ(W_1 (y − μ)/s) …)`` with a zero-initialized last layer.

    ``shift``/``scale`` (μ, s) standardize the input; set them from training data
    with :meth:`fit_input_scaling` (they are buffers, saved with the state dict).
    """

    def __init__(self, n_in: int, n_out: int, hidden=(256, 256), activation=nn.Tanh):
        super().__init__()
        self.body = dense(n_in, n_out, hidden, activation)
        self.register_buffer("shift", torch.zeros(n_in))
        self.register_buffer("scale", torch.ones(()))

    def fit_observations(self, y, noise: float | None = None, **settings) -> MLP:
        """The preconditioning hook (:func:`fit_preconditioning`): per-node standardization (the
        whitening's ``settings`` do not apply)."""
        return self.fit_input_scaling(y)

    @torch.no_grad()
    def fit_input_scaling(self, y: torch.Tensor) -> MLP:
        """μ = mean of the training inputs, s = their overall standard deviation."""
        y = torch.as_tensor(y, dtype=self.shift.dtype)
        self.shift.copy_(y.mean(0))
        self.scale.copy_((y - y.mean(0)).std().clamp_min(1e-12))
        return self

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.body((y - self.shift) / self.scale)


def dense(n_in: int, n_out: int, hidden=(256, 256), activation=nn.Tanh) -> nn.Sequential:
    """``W_L σ(… σ(W_1 z) …)`` with a zero-initialized last layer (no input scaling)."""
    layers, width = [], n_in
    for h in hidden:
        layers += [nn.Linear(width, h), activation()]
        width = h
    return zero_last_layer(nn.Sequential(*layers, nn.Linear(width, n_out)))


@torch.no_grad()
def zero_last_layer(model: nn.Module) -> nn.Module:
    """Set the weight and bias of ``model``'s last ``nn.Linear`` (in ``modules()`` order) to zero;
    returns ``model``.

    Do this to a network of your own: a random head emits components the physics cannot
    see, and no update rule removes them (measured on heat_2d, 20 s SIP: 0.44 with torch's
    random head, 0.27 with a zero head). ``ValueError`` if the model has no ``nn.Linear``.
    """
    linears = [m for m in model.modules() if isinstance(m, nn.Linear)]
    if not linears:
        raise ValueError(f"zero_last_layer: {type(model).__name__} has no torch.nn.Linear layer; "
                         "zero its output layer's weight and bias yourself")
    nn.init.zeros_(linears[-1].weight)
    if linears[-1].bias is not None:
        nn.init.zeros_(linears[-1].bias)
    return model


class Residual(nn.Module):
    """``x = A z + b + g(z)``: a linear path plus a dense correction ``g``, both heads starting at zero."""

    def __init__(self, n_in: int, n_out: int, hidden=(256, 256), activation=nn.Tanh):
        super().__init__()
        self.linear = dense(n_in, n_out, ())
        self.correction = dense(n_in, n_out, hidden, activation)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.linear(z) + self.correction(z)


class Net(nn.Module):
    """``x = post(body(pre(y)))``: a fitted input transform ``pre`` (e.g.
    :class:`~pdeinv.precondition.Whitening`), a trainable ``body`` and a fixed output map
    ``post`` (default: none; :class:`Decoder` in :func:`reduced`). :meth:`fit_observations`
    fits ``pre`` on training observations."""

    def __init__(self, pre: nn.Module, body: nn.Module, post: nn.Module | None = None):
        super().__init__()
        self.pre, self.body = pre, body
        self.post = nn.Identity() if post is None else post

    def fit_observations(self, y, noise: float | None = None, **settings) -> Net:
        fit = getattr(self.pre, "fit_observations", None)
        if callable(fit):
            fit(y, noise, **settings)
        return self

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.post(self.body(self.pre(y)))

    @property
    def decoder(self) -> torch.Tensor | None:
        """The fixed output map's rows ``Dᵀ`` (``(k, N)``; :class:`Decoder`), ``None`` without one: the
        network's fields lie in ``span D`` whatever its body (targets and inverses work there)."""
        return getattr(self.post, "basis", None)

    def linear_in_parameters(self) -> LinearInParameters | None:
        """The structure ``x = D(W z(y) + b)`` when the body is one ``nn.Linear`` (alone or as the
        only module of an ``nn.Sequential``) holding every trainable parameter: ``z = pre(y)`` is a
        fixed feature map and ``D`` the fixed output map (:class:`Decoder` or the identity). ``None``
        for any other body. Update rules use it to work with the exact Kronecker structure of the
        Jacobian (:meth:`gauss_newton_diagonal`; HIG's ``kronecker`` route)."""
        body = self.body
        if isinstance(body, nn.Sequential) and len(body) == 1:
            body = body[0]
        trainable = [p for p in self.parameters() if p.requires_grad]
        if type(body) is not nn.Linear or len(trainable) != len(list(body.parameters())) or \
                not all(p.requires_grad for p in body.parameters()):
            return None
        return LinearInParameters(self.pre, self.decoder, body)

    @torch.no_grad()
    def gauss_newton_diagonal(self, y: torch.Tensor) -> tuple[torch.Tensor, ...] | None:
        """The diagonal of ``G = (1/B) JᵀJ`` (``J = ∂ vec x / ∂θ`` on the batch ``y``) per trainable
        parameter, in ``parameters()`` order, when the network is linear in them,
        ``x = D(W z + b)`` (:meth:`linear_in_parameters`)::

            G = (Z̃ᵀZ̃/B) ⊗ (DᵀD),   diag G[W_ji] = (DᵀD)_jj · mean_b z_bi²,   diag G[b_j] = (DᵀD)_jj

        ``None`` otherwise. With the whitened input (``Z̃ᵀZ̃/B`` = I on the full training set) and a
        decoder with orthogonal columns ``G`` *is* diagonal, and dividing by it is Newton's step
        (:class:`~pdeinv.SIP`)."""
        lin = self.linear_in_parameters()
        if lin is None:
            return None
        z2 = (lin.features(y).to(lin.layer.weight.dtype) ** 2).mean(0)
        rows = torch.ones(lin.layer.out_features, dtype=z2.dtype, device=z2.device) if lin.decoder is None \
            else (lin.decoder.to(z2.dtype) ** 2).sum(1)
        diag = {"weight": rows[:, None] * z2[None, :], "bias": rows}
        return tuple(diag[name] for name, _ in lin.layer.named_parameters())


    @torch.no_grad()
    def gauss_newton_max(self, y: torch.Tensor) -> float | None:
        """``λ_max(d^{-1/2} G d^{-1/2})`` exactly, ``d`` = :meth:`gauss_newton_diagonal` (zeros read as 1),
        when the network is linear in its parameters; ``None`` otherwise. ``G = A ⊗ C`` with
        ``A = Z̃ᵀZ̃/B`` and ``C = DDᵀ`` (:meth:`gauss_newton_diagonal`), and ``d = diag(C) ⊗ diag(A)``,
        so the normalized matrix is the Kronecker product of the normalized factors and its largest
        eigenvalue the product of theirs: two small symmetric eigenproblems (``k̃ × k̃`` and
        ``k_out × k_out``) instead of :func:`~pdeinv.methods.curvature.gauss_newton_max`'s 30 power
        iterations through the network (heat_2d, the full batch: ~0.5 s against ~5 s, one thread)."""
        lin = self.linear_in_parameters()
        if lin is None:
            return None
        z = lin.features(y).double()
        if lin.layer.bias is not None:
            z = torch.cat([z, torch.ones(len(z), 1, dtype=z.dtype, device=z.device)], 1)
        factors = [z.T @ z / len(z)]
        if lin.decoder is not None:
            D = lin.decoder.double()
            factors.append(D @ D.T)
        lam = 1.0
        for S in factors:
            d = S.diagonal().clone()
            r = torch.where(d > 0, d, torch.ones_like(d)).rsqrt()
            lam *= float(torch.linalg.eigvalsh(S * r[:, None] * r[None, :]).max())
        return lam


class LinearInParameters(NamedTuple):
    """``x = D(W z(y) + b)`` (:meth:`Net.linear_in_parameters`): the fixed feature map ``z``, the fixed
    decoder's rows ``Dᵀ`` (``(k_out, N)``, ``None`` for the identity), and the ``nn.Linear`` holding
    ``W`` and ``b`` (its ``named_parameters()`` order is the network's trainable order)."""

    features: Callable[[torch.Tensor], torch.Tensor]
    decoder: torch.Tensor | None
    layer: nn.Linear


#: the default networks' dtype. They are linear estimators fitted to float64 physics: noise-free, what
#: they can recover is bounded by their arithmetic (float32 rounds inputs at ~6e-8 of the largest
#: amplitude; a heat scene's weak modes sit far below). Measured (SIP, 1000 steps, heat_1d): float64
#: with the float64 whitening floor 0.017, float32 0.040 (best-α Tikhonov 0.021). A float64 product
#: costs about twice the float32 one on CPU.
DTYPE = torch.float64

#: at most this many decoder columns out of :func:`reduced` (``k_out``); fewer when they hold all but
#: :data:`REDUCED_UNCAPTURED` of the prior's energy. Measured in closed form (the decoder's
#: rounding-level solve on 128 noise-free test pairs): heat_3d 0.0209 with 256 columns (5.2e-5 of the
#: prior's energy outside), 0.0122 with 512 (3.9e-7), 0.0119 with all 729; heat_2d, heat_plate and
#: the sensor scenes need ~270 (below 1e-10 outside).
REDUCED_K = 512

#: the fraction of the prior's energy (``E‖x‖²_M``) the decoder may leave out: an error floor of
#: ``√1e-10 = 1e-5`` relative, far below what any scene's observations resolve
REDUCED_UNCAPTURED = 1e-10

#: leading whitened components into :func:`reduced` (``k_in``). 1024 rather than 256: with noisy
#: observations the denoised target depends on y's coordinates along the kept modes, which 256 data
#: directions capture only in part. Measured (SIP, CLI defaults, 20 full-batch steps, one thread):
#: heat_plate at 1 % noise 0.146 → 0.142 (best-α Tikhonov 0.141, the closed-form target 0.1405;
#: k_in = 2560 gives 0.142 too: 1024 training rows span no more), wave_sensors_2d 0.0032 → 0.0028
#: (noise-free 5e-5 → 4e-5), heat_plate noise-free 0.049 → 0.050.
REDUCED_K_IN = 1024

#: the largest fraction of the prior's energy a decoder may leave out before :func:`linear_default`
#: takes the whitened map instead (an error floor of 0.1 %)
DECODER_MAX_UNCAPTURED = 1e-6

#: whitened components of the linear part where no decoder is used for the prior (:func:`linear_default`'s
#: fallback, :func:`data_base`): ``N·k`` parameters, linear in the mesh. The training rows bound the
#: whitening's rank anyway (heat_boxes 64×64, SIP noise-free: 0.1715 with 1024 or 2048 components and
#: with all 3 969, which carry 2 945 dead columns; 4.1 M / 8.1 M / 15.8 M parameters)
FALLBACK_COMPONENTS = 2048

#: unknowns above which :func:`default_model` builds :func:`reduced` even for a reversible operator
#: (measured on heat_2d; the table is in :func:`reduced`)
REDUCED_ABOVE = 2_000


def default_model(problem, rows_per_component: float | None = None, refine: bool = True,
                  base: str = "auto") -> nn.Module:
    """The problem's default network: a linear estimate (below; ``base='whitened'`` forces the whitened
    map, what a user's data file gets, :func:`data_base`) and, with ``refine``, the nonlinear correction
    fitted on prior draws (:func:`refined`, :mod:`pdeinv.refine`). The linear part is chosen by what the
    operator is (:func:`pdeinv.physics.capabilities.reversible`):

    * a **reversible** operator (the wave scenes' final state: an energy-conserving, time-reversible
      map) loses nothing: every ``x`` is recoverable from ``y`` to rounding, and a network restricted
      to a prior subspace could only add the prior's uncaptured part. It gets the whitened linear map
      (:func:`whitened`; wave_2d SIP 5e-9) up to :data:`REDUCED_ABOVE` unknowns or observations.
    * every other operator (heat: dissipative; sensors: partial) has directions ``y`` does not see,
      which only the prior can fill. It gets :func:`reduced`, whose fixed decoder is the prior's
      principal components: the rules then solve *in the decoder's span*
      (:class:`~pdeinv.inverse.decoder.DecoderTikhonov`) and the noisy target is the Wiener filter in
      the basis of ``P D`` (:class:`~pdeinv.targets.SpectralWiener`), which reaches the linear MMSE.
      Measured in closed form (1024 training observations, 128 test pairs; relative L²(Ω)
      x-errors, noise-free / 1 %; best-α Tikhonov and the MMSE fitted on the *training x* in
      brackets): heat_2d 0.0085 / 0.0908 (0.037 / 0.117; MMSE 0.090 at 1 %), heat_sensors_2d
      0.012 / 0.102 (0.045 / 0.147; 0.101), advection_diffusion_2d 0.0089 / 0.097 (0.034 / 0.124;
      0.097), heat_sensors_3d 0.050 / 0.156 (0.064 / 0.206; 0.155), heat_cavity_3d 0.0099 / 0.070
      (0.067 / 0.186; 0.072), heat_plate 0.0101 / 0.088 (0.066 / 0.142; 0.086), heat_1d 0.015 /
      0.119 (0.024 / 0.127; 0.119).

    ``rows_per_component`` caps the whitened directions for first-order rules
    (:class:`~pdeinv.precondition.Whitening`; ``--method gd`` and ``adam`` use 8,
    :mod:`pdeinv.methods.presets`). Those rules keep the whitened linear map below
    :data:`REDUCED_ABOVE` on every scene: they stop far from the fit in the decoder's span that makes
    the prior extrapolate. Measured (Adam, CLI defaults, 1000 steps): heat_cavity_3d 0.315 with the
    decoder against 0.171, heat_sensors_2d 0.314 against 0.262 (heat_2d 0.263 against 0.286)."""
    if base not in ("auto", "whitened"):
        raise ValueError(f"base={base!r} is not allowed; expected 'auto' or 'whitened'")
    net = _whitened_fallback(problem, rows_per_component) if base == "whitened" else \
        linear_default(problem, rows_per_component)
    return refined(problem, net) if refine else net


def data_base(problem) -> str:
    """The linear part for a user's data file (``default_model``'s ``base``): ``'whitened'``, the whitening
    fitted on the file's ``y`` with at most :data:`FALLBACK_COMPONENTS` components, so that nothing comes
    from the scene's sampler (a prior decoder would be the scene's prior: heat_2d files from other priors,
    SIP 1.31–1.68× best-α Tikhonov with it, and the whitened map better in all six cases measured, issue
    32)."""
    return "whitened"


def _whitened_fallback(problem, rows_per_component=None) -> nn.Module:
    return whitened("linear", rows_per_component=rows_per_component, components=FALLBACK_COMPONENTS)(problem)


def linear_default(problem, rows_per_component: float | None = None) -> nn.Module:
    """The linear part of :func:`default_model` (the default before :mod:`pdeinv.refine`; ``--net
    linear``): :func:`reduced` or :func:`whitened` as described there. A decoder that leaves more than
    :data:`DECODER_MAX_UNCAPTURED` of the prior's energy out has an error floor of its square root
    (the SIP paper's boxes at 64×64: 512 components leave 1.3 %, SIP 1.07 against 0.14 for the whitened
    map, its rounding-level solve amplifying the missing part): the whitened linear map with at most
    :data:`FALLBACK_COMPONENTS` components is taken instead (parameters linear in the mesh)."""
    big = max(problem.operator.n_in, problem.operator.n_out) > REDUCED_ABOVE
    kw = {"rows_per_component": rows_per_component}
    if not (big or _prior_decoded(problem, rows_per_component)):
        return whitened("linear", **kw)(problem)
    net = reduced(**kw)(problem)
    info = getattr(net, "decoder_info", {})
    if 1 - info.get("captured", 1.0) > DECODER_MAX_UNCAPTURED:
        return _whitened_fallback(problem, rows_per_component)
    return net


def refined(problem, base: nn.Module) -> nn.Module:
    """``base`` plus a nonlinear correction on a grid fitted on prior draws (:class:`pdeinv.refine.Refined`),
    for a problem whose unknowns are nodal values on a mesh of dimension 1–3; ``base`` otherwise. Where
    the operator has a modal basis (the heat scenes' modal backend) the correction also sees the
    physics' own Tikhonov estimate (:class:`pdeinv.refine.SpectralFilter`, α at the noise level or at
    rounding): full rank, where ``base`` is learned from the training rows and has at most their rank
    (heat_boxes n=96: base 0.600 against best-α Tikhonov 0.108)."""
    from .grid import GridMap, spacing
    from .inverse import NOISE_FREE_REL_ALPHA
    from .physics.capabilities import modal_basis
    from .refine import Refined, SpectralFilter

    disc = getattr(problem, "disc", None)
    mesh = getattr(getattr(disc, "basis", None), "mesh", None)
    if mesh is None or not 1 <= problem.points.shape[0] <= 3:
        return base
    modes = modal_basis(problem.operator)  # a full-rank physics estimate as a second input, where cheap
    noise = float(getattr(problem, "noise", 0.0) or 0.0)
    physics = None if modes is None else SpectralFilter(modes, max(noise, NOISE_FREE_REL_ALPHA**0.5) ** 2)
    return Refined(base, GridMap(problem.points, spacing(mesh)), physics=physics)


def _prior_decoded(problem, rows_per_component) -> bool:
    """Whether :func:`default_model` gives ``problem`` the prior decoder at any size: a non-reversible
    operator, trained by a rule that converges (no ``rows_per_component`` cap)."""
    from .physics.capabilities import reversible

    return rows_per_component is None and not reversible(problem.operator)


def default_size(problem) -> tuple[int, int]:
    """``(parameters + buffers, widest layer)`` of :func:`default_model`'s network for ``problem``,
    without building it (the memory guard, :func:`pdeinv.memory.check_training`; an upper bound:
    the decoder may keep fewer than :data:`REDUCED_K` columns); a problem
    with its own ``model_factory`` gets the dense bound ``m² + m n + n`` (an upper bound for
    the scenes' MLP)."""
    m, n = problem.operator.n_out, problem.operator.n_in
    k = min(m, n)  # the whitening's components (:func:`whitened`)
    dense = m * k + k * n + n
    if getattr(problem, "model_factory", None) is not None:
        return dense, max(m, n)
    if max(m, n) > REDUCED_ABOVE or _prior_decoded(problem, None):
        k_in, k_out = min(REDUCED_K_IN, m), min(REDUCED_K, n)
        size = k_in * k_out + k_out + m * k_in + n * k_out + m + k_in
        # a decoder that misses the prior falls back to the whitened map (linear_default)
        kf = min(m, n, FALLBACK_COMPONENTS)
        dense = max(size, m * kf + kf * n + n)
    return dense + refined_size(problem), max(m, n)


def network_size(problem, kind: str = "default", hidden=None) -> dict:
    """What the network of ``--net kind`` (or the MLP of ``--hidden``) for ``problem`` will hold, without
    building it: ``params`` (trained), ``buffers`` (fixed arrays: whitening basis, decoder, grid maps),
    ``build`` (bytes its construction needs on top: the prior draws and Gram matrix of
    :func:`prior_basis`), ``widest`` (its widest layer) and ``dtype_bytes``. Upper bounds (a decoder may
    keep fewer columns); the memory guard (:func:`pdeinv.memory.check_training`) adds the training state
    per parameter. ``kind``: 'default', 'linear', 'whitened', 'reduced' or 'mlp' (``hidden`` given)."""
    m, n = problem.operator.n_out, problem.operator.n_in
    itemsize = torch.finfo(DTYPE).bits // 8

    def whitened_size(k):  # built as an identity basis and a linear layer: nothing on top
        return {"params": k * n + n, "buffers": m * k + k + m + 1, "build": 0}

    def reduced_size():
        k_in, k_out = min(REDUCED_K_IN, m), min(REDUCED_K, n)
        draws = 4 * k_out  # prior_basis: 4k draws of the prior, their Gram matrix, QR of N × k
        return {"params": k_in * k_out + k_out, "buffers": m * k_in + k_in + m + 1 + n * k_out,
                "build": 8 * (draws * n + draws**2 + 2 * n * k_out)}

    if hidden:
        from .memory import network_parameters

        size = {"params": network_parameters(m, n, hidden), "buffers": 2 * m, "build": 0}
        return {**size, "widest": max(m, n, *hidden), "dtype_bytes": 4}
    if kind == "whitened":
        size = whitened_size(min(m, n))
    elif kind == "reduced":
        size = reduced_size()
    elif kind in ("default", "linear"):
        if getattr(problem, "model_factory", None) is not None:
            k = min(m, n)
            size = {"params": m * k + k * n + n, "buffers": 0, "build": 0}
        elif max(m, n) > REDUCED_ABOVE or _prior_decoded(problem, None):
            red, fall = reduced_size(), whitened_size(min(m, n, FALLBACK_COMPONENTS))
            # the decoder is built first; a decoder that misses the prior falls back to the whitened map
            size = {k: max(red[k], fall[k]) for k in ("params", "buffers")}
            size["build"] = red["build"]
        else:
            size = whitened_size(min(m, n))
        if kind == "default":  # the correction (pdeinv.refine): U-Net parameters (trained) and grid maps
            size["params"] += refined_size(problem)
    else:
        raise ValueError(f"kind={kind!r} is not allowed; expected 'default', 'linear', 'whitened' or "
                         "'reduced' (or hidden widths for the MLP)")
    return {**size, "widest": max(m, n), "dtype_bytes": itemsize}


def refined_size(problem) -> int:
    """An upper bound on what :func:`refined` adds: the U-Net's parameters and the grid maps' buffers
    (``2·N·2^dim`` weights and indices, at most ``4N`` grid points); 0 where it adds nothing."""
    from .refine import UNet

    dim = problem.points.shape[0] if getattr(problem, "disc", None) is not None else 0
    if not 1 <= dim <= 3:
        return 0
    return sum(q.numel() for q in UNet(dim).parameters()) + 2 * problem.N * 2**dim + 4 * problem.N


def fit_preconditioning(model: nn.Module, y, noise: float | None = None, **settings) -> nn.Module:
    """Fit ``model``'s input transform on training observations ``y`` (never on ``x``).

    Calls ``model.fit_observations(y, noise, **settings)`` if the model has one (:class:`Net`,
    :class:`MLP`); ``noise`` is the relative noise level when known (it sets the whitening floor);
    ``settings`` go to the whitening (``drop=0``: floor at the noise, drop nothing). Other models
    are left alone.
    """
    fit = getattr(model, "fit_observations", None)
    if callable(fit):
        fit(y, noise, **settings)
    return model


#: bodies of the whitened networks: name -> (n_in, n_out, hidden, activation) -> module
BODIES = {
    "linear": lambda n_in, n_out, hidden, act: dense(n_in, n_out, ()),
    "mlp": dense,
    "residual": Residual,
}


def whitened(body: str = "linear", hidden=(256, 256), activation=nn.Tanh, rel_floor: float | None = None,
             drop: float | str = "edge", dtype: torch.dtype = DTYPE, rows_per_component: float | None = None,
             components: int | None = None):
    """A ``model_factory``: :class:`Net` of a :class:`Whitening` and a body from :data:`BODIES`, in
    ``dtype`` (default float64: see :data:`DTYPE`). With more observations than unknowns
    (``m > N``: sensor time series) the whitening keeps the ``N`` leading components: noise-free
    observations ``y = P x`` span at most ``N`` directions, so nothing is lost, and the buffers and
    the body shrink from ``m`` to ``N`` inputs (wave_sensors_2d: 3072 → 1089). ``rows_per_component``:
    keep at most one whitened direction per that many training rows (for first-order rules,
    :class:`~pdeinv.precondition.Whitening`)."""
    if body not in BODIES:
        raise ValueError(f"body={body!r} is not allowed; expected one of {', '.join(map(repr, BODIES))}")

    def factory(problem) -> nn.Module:
        m, n = problem.operator.n_out, problem.operator.n_in
        k = min(m, n) if components is None else min(components, m, n)
        pre = Whitening(m, rel_floor, drop, components=k if k < m else None,
                        rows_per_component=rows_per_component)
        return Net(pre, BODIES[body](pre.k, n, tuple(hidden), activation)).to(dtype)

    return factory


def mlp(hidden=(256, 256), activation=nn.Tanh):
    """A ``model_factory`` for :class:`pdeinv.Problem`: ``Problem(..., model_factory=mlp((128, 128)))``.

    The factory receives the problem and sizes the MLP to it (observations in,
    unknowns out).
    """

    def factory(problem) -> nn.Module:
        return MLP(problem.operator.n_out, problem.operator.n_in, hidden=tuple(hidden),
                   activation=activation)

    return factory


class Decoder(nn.Module):
    """``x = Φ c``: a fixed basis ``Φ`` (``N × k``, a buffer, not trained) times coefficients ``c``."""

    def __init__(self, basis: torch.Tensor):
        super().__init__()
        self.register_buffer("basis", torch.as_tensor(basis).T.contiguous())  # stored (k, N)

    def forward(self, c: torch.Tensor) -> torch.Tensor:
        return c @ self.basis

    def extra_repr(self) -> str:
        k, n = self.basis.shape
        return f"N={n}, k={k}"


def prior_basis(problem, k: int, samples: int | None = None, seed: int = 20_161, chunk: int = 128,
                scaled: bool = True, uncaptured: float = 0.0):
    """``Φ`` (``N × k'``): the span of the ``k' ≤ k`` leading L²(Ω) principal components of fields
    drawn from the problem's prior (``problem.sampler``), with Euclidean-orthonormal columns.

    The M-principal directions maximize the captured ``E‖x‖²_M`` (second moment, not centred, so
    the prior mean is in the span too): the generalized eigenvectors of ``(M C M, M)`` with
    ``C = XᵀX`` of the ``n`` drawn fields ``X`` (rows), computed on whichever side is smaller —
    ``N × N`` when ``N < n``, else from the ``n × n`` Gram ``X M Xᵀ = U S² Uᵀ`` as ``Xᵀ U S⁻¹`` —
    then a QR makes the columns orthogonal in ``ℝᴺ``. ``k' = k`` unless fewer components hold
    all but a fraction ``uncaptured`` of the drawn energy (or the draws have lower rank).
    ``scaled=True`` (default) then scales column ``j`` by the prior's rms
    amplitude ``σ_j`` along it, normalized so that ``Σ_j ‖Φ_j‖² = N`` (the trace of the
    identity, which is the decoder of a network with nodal outputs): an optimizer step that
    moves every coefficient by ``ε`` moves the field by ``ε`` per node in the mean, whatever
    ``N`` (so Adam's learning rates keep their meaning across meshes), and mostly along the
    directions the prior fills. Measured (heat_2d, SIP Adam 1e-3, n = 16, 300 steps): x-error
    0.14 scaled against 1.0 with orthonormal columns (Adam's sign-like steps pushed the
    low-variance, invisible directions as hard as the leading ones); without the ``N``
    normalization the error at n = 64 was 6x that at n = 32. ``info``: the captured fraction.
    Deterministic (``seed``), so a saved network rebuilds the same buffer.
    """
    import numpy as np
    import scipy.linalg as sla

    n = samples or 4 * k
    rng = np.random.default_rng(seed)
    X = np.vstack([problem.sampler(min(chunk, n - i), rng) for i in range(0, n, chunk)])
    M = problem.disc.M if getattr(problem, "disc", None) is not None else None
    N = X.shape[1]
    if N < n:  # the N × N side: generalized eigenvectors of (M XᵀX M, M), M-orthonormal
        Md = np.eye(N) if M is None else M.toarray()
        XM = X @ Md
        lam, vecs = sla.eigh(XM.T @ XM, Md)
    else:  # the n × n side: X M Xᵀ = U S² Uᵀ, directions Xᵀ U S⁻¹
        lam, vecs = np.linalg.eigh(X @ (M @ X.T) if M is not None else X @ X.T)
    lam, vecs = lam[::-1], vecs[:, ::-1]
    rank = int((lam > lam[0] * 1e-14).sum())
    tail = 1.0 - np.cumsum(lam[:rank]) / lam[lam > 0].sum()  # uncaptured after j + 1 components
    k = min(k, rank, int(np.searchsorted(-tail, -uncaptured)) + 1)
    dirs = vecs[:, :k] if N < n else X.T @ (vecs[:, :k] / np.sqrt(lam[:k]))
    Phi = np.linalg.qr(dirs)[0]
    if scaled:  # column j ∝ the prior's rms amplitude along it, Σ_j ‖Φ_j‖² = N (see the docstring)
        rms = np.sqrt(((X @ Phi) ** 2).mean(0))
        Phi = Phi * (rms * np.sqrt(N / (rms**2).sum()))
    return Phi, {"captured": float(lam[:k].sum() / lam[lam > 0].sum()), "components": k, "samples": n}


def reduced(k_in: int = REDUCED_K_IN, k_out: int = REDUCED_K, body: str = "linear", hidden=(256, 256),
            activation=nn.Tanh, rel_floor: float | None = None, drop: float | str = "edge",
            samples: int | None = None, dtype: torch.dtype = DTYPE, scaled: bool = True,
            rows_per_component: float | None = None, uncaptured: float = REDUCED_UNCAPTURED):
    """A ``model_factory`` whose *trained* size does not depend on the mesh:

        x = Φ · body(z),   z = D_k U_kᵀ (y − μ)

    ``z``: the ``k_in`` leading whitened PCA components of the observations
    (:class:`~pdeinv.precondition.Whitening` with ``components=k_in``, fitted on the training
    observations); ``body``: a network ``k_in → k_out`` from :data:`BODIES` with a
    zero-initialized last layer; ``Φ``: a *fixed* decoder basis (``N × k_out``,
    :func:`prior_basis`: the leading principal components of the prior's fields, a buffer).
    Parameters: ``k_in·k_out + k_out`` for the linear body (262 400 at the defaults; the table
    below was measured with ``k_in`` = 256, 65 792),
    whatever ``N``; buffers ``(m + N)·k`` grow linearly. Everything outside the span of
    ``Φ`` is out of reach: the error floor is the prior's uncaptured part.

    **Measured** with ``python benchmarks/netsize.py`` (heat_2d, noise-free, the CLI's
    defaults: SIP (Adam 1e-3), 1000 steps, 1024 training and 128 test pairs, seed 0, one
    thread; 2 shared cores at load 4–6, so compare within a row pair; x-error: mean relative
    L²(Ω) on the test set; RSS: peak of the process):

    ====  ======  ==============  ============  ========  ========  ======
    n     N       network         trained       x-error   s/step    RSS GB
    ====  ======  ==============  ============  ========  ========  ======
    32    961     whitened lin.   924 482       0.0261    0.093     0.44
    32    961     reduced         65 792        0.0307    0.045     0.39
    64    3 969   whitened lin.   15 756 930    0.0298    1.19      1.17
    64    3 969   reduced         65 792        0.0337    0.127     0.66
    128   16 129  whitened lin.   260 160 770   (5 steps) 39.8      10.8
    128   16 129  reduced         65 792        0.0379    0.344     1.67
    ====  ======  ==============  ============  ========  ========  ======

    With Adam through the physics (``--method adam``) at n = 32: 0.262 (reduced, 0.013 s/step)
    against 0.284 (whitened linear, 0.026 s/step); reduced at n = 64: 0.289 (0.020 s/step),
    n = 128: 0.304 (0.066 s/step).

    At n = 64 the whitened linear map is slightly more accurate (0.030 against 0.034) for 9x the
    step time; at n = 128 it would need ~11 h for the 1000 steps (its step is ~120x the
    reduced one and the memory 6.5x). The reduced network's error grows only
    slowly with N (0.031 → 0.038; the heat problem's recoverable content does not grow
    with the mesh) and its step time is the physics'. Hence :data:`REDUCED_ABOVE` = 2 000:
    heat_2d at its default n = 32 keeps the whitened linear map (better by 0.005 there),
    n ≥ 46 switches. Body: ``linear`` (at n = 32, with the decoder before its ``N``
    normalization: 0.042 against 0.094 for ``mlp`` (256, 256), as for the full-size
    networks). Decoder scaling: :func:`prior_basis`.
    """
    if body not in BODIES:
        raise ValueError(f"body={body!r} is not allowed; expected one of {', '.join(map(repr, BODIES))}")
    for name, k in (("k_in", k_in), ("k_out", k_out)):
        if isinstance(k, bool) or not isinstance(k, int) or k < 1:
            raise ValueError(f"{name}={k!r} is not allowed; expected an integer >= 1")

    def factory(problem) -> nn.Module:
        m, n = problem.operator.n_out, problem.operator.n_in
        basis, info = prior_basis(problem, min(k_out, n), samples, scaled=scaled, uncaptured=uncaptured)
        pre = Whitening(m, rel_floor, drop, components=min(k_in, m), rows_per_component=rows_per_component)
        net = Net(pre, BODIES[body](pre.k, basis.shape[1], tuple(hidden), activation),
                  Decoder(torch.as_tensor(basis, dtype=dtype))).to(dtype)
        net.decoder_info = info
        return net

    return factory
