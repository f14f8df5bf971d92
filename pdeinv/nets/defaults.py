"""Which network a problem gets by default (:func:`default_model`) and how large it is (:func:`default_size`):
the linear part (prior decoder, whitened map or its capped fallback) and the nonlinear correction on a grid
(:func:`refined`, :mod:`pdeinv.nets.refine`)."""

from __future__ import annotations

import torch
from torch import nn

from .._checks import flag, shown, widths
from .._checks import problem as _problem
from ..physics.nonlinear import is_linear
from .net import DTYPE, whitened
from .protocol import declared
from .reduced import REDUCED_K_IN, REDUCED_K_MAX, decoder_uncaptured, reduced
from .whitening import check_settings

#: the largest fraction of the prior's energy a decoder may leave out before :func:`linear_default`
#: takes the whitened map instead (an error floor of 0.1 %)
DECODER_MAX_UNCAPTURED = 1e-6


#: whitened components of the linear part where no decoder is used for the prior (:func:`linear_default`'s
#: fallback, :func:`data_base`): ``N·k`` parameters, linear in the mesh. The training rows bound the
#: whitening's rank anyway: on heat_boxes 64×64 more components than rows only add dead columns
FALLBACK_COMPONENTS = 2048


#: unknowns above which :func:`default_model` builds :func:`reduced` even for a reversible operator: above
#: it the whitened linear map's step grows with ``N·m`` while its accuracy gain is small (heat_2d, n ≥ 46)
REDUCED_ABOVE = 2_000

#: the largest mesh whose correction is the dense MLP (:func:`correction_kind`): its first layer has
#: ``(m + 2N)·512`` weights (6 M at this size)
DENSE_MAX_UNKNOWNS = 4096

#: the dense correction's hidden widths (:class:`~pdeinv.nets.corrections.DenseCorrection`)
DENSE_HIDDEN = (512, 512, 512)


def default_model(problem, rows_per_component: float | None = None, refine: bool = True,
                  base: str = "auto", correction: str = "auto") -> nn.Module:
    """The problem's default network: a linear estimate (below; ``base='whitened'`` forces the whitened
    map, what a user's data file gets, :func:`data_base`) and, with ``refine``, the nonlinear correction
    fitted on prior draws (:func:`refined`, :mod:`pdeinv.nets.refine`; ``correction`` its kind). The
    linear part is chosen by what the
    operator is (:func:`pdeinv.physics.capabilities.reversible`):

    * a **reversible** operator (the wave scenes' final state: an energy-conserving, time-reversible
      map) loses nothing: every ``x`` is recoverable from ``y`` to rounding, and a network restricted
      to a prior subspace could only add the prior's uncaptured part. It gets the whitened linear map
      (:func:`whitened`; wave_2d SIP 5e-9) up to :data:`REDUCED_ABOVE` unknowns or observations.
    * every other operator (heat: dissipative; sensors: partial) has directions ``y`` does not see,
      which only the prior can fill. It gets :func:`reduced`, whose fixed decoder is the prior's
      principal components: the rules then solve *in the decoder's span*
      (:class:`~pdeinv.inverse.decoder.DecoderTikhonov`) and the noisy target is the Wiener filter in
      the basis of ``P D`` (:class:`~pdeinv.methods.targets.SpectralWiener`), which reaches the linear MMSE
      (below best-α Tikhonov on every heat scene: benchmarks/notes/results-history.md).

    ``rows_per_component`` caps the whitened directions for first-order rules
    (:class:`~pdeinv.nets.whitening.Whitening`; ``--method gd`` and ``adam`` use 8,
    :mod:`pdeinv.methods.presets`). Those rules keep the whitened linear map below
    :data:`REDUCED_ABOVE` on every scene: they stop far from the fit in the decoder's span that makes
    the prior extrapolate (Adam on heat_cavity_3d: x-error 0.315 with the decoder, 0.171 without)."""
    _problem(problem)
    check_settings(rows_per_component=rows_per_component)
    flag(refine, "refine")
    if not isinstance(base, str) or base not in ("auto", "whitened"):
        raise ValueError(f"base={shown(base)} is not allowed; expected 'auto' or 'whitened'")
    _correction(correction)
    net = _whitened_fallback(problem, rows_per_component) if base == "whitened" else \
        linear_default(problem, rows_per_component)
    return refined(problem, net, correction) if refine else net


def data_base(problem) -> str:
    """The linear part for a user's data file (``default_model``'s ``base``): ``'whitened'``, the whitening
    fitted on the file's ``y`` with at most :data:`FALLBACK_COMPONENTS` components, so that nothing comes
    from the scene's sampler (a prior decoder would be the scene's prior, and on heat_2d files drawn from
    other priors it left SIP up to 1.7× best-α Tikhonov)."""
    _problem(problem)
    return "whitened"


def _whitened_fallback(problem, rows_per_component=None) -> nn.Module:
    return whitened("linear", rows_per_component=rows_per_component, components=FALLBACK_COMPONENTS)(problem)


#: whitened directions of the linear map per training row where the physics is nonlinear: no linear map
#: fits the rows exactly, and whatever residual the trailing directions absorb is amplified on new data
#: (Marchenko–Pastur, as for GD and Adam in :mod:`pdeinv.methods.presets`). 8: on sine_gordon_2d all
#: directions left a held-out x-error of 4.65, this cap 0.56
NONLINEAR_ROWS_PER_COMPONENT = 8


def linear_default(problem, rows_per_component: float | None = None) -> nn.Module:
    """The linear part of :func:`default_model` (the default before :mod:`pdeinv.nets.refine`; ``--net
    linear``): :func:`reduced` or :func:`whitened` as described there. A decoder that leaves more than
    :data:`DECODER_MAX_UNCAPTURED` of the prior's energy out has an error floor of its square root
    (its rounding-level solve amplifies the missing part): :func:`_missed_prior` is taken instead, the
    linear map in the operator's modes (:func:`pdeinv.nets.modal.modal`: ``O(k²)`` numbers, not ``O(N·k)``)
    for a rule that converges, the whitened linear map with at most :data:`FALLBACK_COMPONENTS` components
    for a first-order rule, whose per-parameter steps move the weakest modes as fast as the strongest
    (Adam on the modal map at heat_boxes 64²: x-error 1.2). On nonlinear
    physics the whitened map, and above :data:`REDUCED_ABOVE` the reduced network's whitened input, keep one
    direction per :data:`NONLINEAR_ROWS_PER_COMPONENT` rows (one direction per row fits the training rows
    and amplifies the held-out residual)."""
    _problem(problem)
    check_settings(rows_per_component=rows_per_component)
    big = max(problem.operator.n_in, problem.operator.n_out) > REDUCED_ABOVE
    kw = {"rows_per_component": rows_per_component}
    nonlinear = rows_per_component is None and not is_linear(problem.operator)
    if not (big or _prior_decoded(problem, rows_per_component)):
        if nonlinear:
            kw["rows_per_component"] = NONLINEAR_ROWS_PER_COMPONENT
        return whitened("linear", **kw)(problem)
    if nonlinear and big:  # the reduced network's whitened input too (sine_gordon_2d at 16 129 unknowns)
        kw["rows_per_component"] = NONLINEAR_ROWS_PER_COMPONENT
    uncaptured = decoder_uncaptured(problem.noise)
    net = reduced(**kw, uncaptured=uncaptured, at_most=max(DECODER_MAX_UNCAPTURED, uncaptured))(problem)
    return _missed_prior(problem, rows_per_component) if net is None else net


def _missed_prior(problem, rows_per_component=None) -> nn.Module:
    """The linear part where the prior decoder misses the prior: the linear map in the operator's modes
    (:func:`pdeinv.nets.modal.modal`) for a rule that converges (``rows_per_component`` None: SIP, HIG) on an
    operator with a spectral basis, else the whitened map with at most :data:`FALLBACK_COMPONENTS`
    components."""
    from .modal import modal, visible_modes

    if rows_per_component is None and visible_modes(problem) is not None:
        return modal()(problem)
    return _whitened_fallback(problem, rows_per_component)



def correction_kind(problem) -> str | None:
    """Which correction :func:`refined` builds for ``problem``: ``'dense'`` (the MLP on ``(y, b(y))``,
    :class:`~pdeinv.nets.corrections.DenseCorrection`) on a mesh of at most :data:`DENSE_MAX_UNKNOWNS`
    unknowns that is 1-D or carries nonlinear physics (declared, :func:`pdeinv.physics.nonlinear.is_linear`),
    ``'grid'`` (the U-Net on a grid) on any other mesh of dimension 1–3, ``None`` without a mesh.

    * A two-level 1-D U-Net sees about 20 neighbouring nodes, a wave or a reaction moves information
      further: the dense MLP wins in 1-D (sine_gordon_1d: 0.064 against the U-Net's 0.190).
    * On nonlinear physics the linear base is far off everywhere (the inverse of a nonlinear map mixes the
      domain), not just at the prior's edges, so the dense MLP wins there too (benchmarks/notes/nonlinear.md).
    * On linear physics in 2-D and 3-D the base is the full linear estimate and what is left is local (the
      edges of a box prior): the U-Net's locality is the right bias there (heat_boxes).
    * ``'span'`` (:class:`~pdeinv.nets.corrections.SpanCorrection`, the MLP in the base's decoder span) on
      larger meshes with nonlinear physics, where the dense MLP's first layer is too large and the U-Net
      misses the mixing (sine_gordon_2d at 16 129 unknowns: 0.20 against the U-Net's 0.56)."""
    from ..physics.nonlinear import is_linear

    _problem(problem)
    mesh = None if problem.disc is None else problem.disc.basis.mesh
    dim = problem.points.shape[0] if mesh is not None else 0
    if not 1 <= dim <= 3:
        return None
    small, nonlinear = problem.N <= DENSE_MAX_UNKNOWNS, not is_linear(problem.operator)
    if not small and nonlinear:
        return "span"  # in the base's decoder span; the U-Net where the base has no decoder (refined)
    return "dense" if small and (dim == 1 or nonlinear) else "grid"


def _correction(correction) -> str:
    """:func:`refined`'s ``correction``: ``'auto'``, ``'grid'``, ``'dense'`` or ``'span'``."""
    if not isinstance(correction, str) or correction not in ("auto", "grid", "dense", "span"):
        raise ValueError(f"correction={shown(correction)} is not allowed; expected 'auto', 'grid', 'dense' "
                         "or 'span'")
    return correction


def refined(problem, base: nn.Module, correction: str = "auto") -> nn.Module:
    """``base`` plus a nonlinear correction fitted on prior draws (:class:`pdeinv.nets.refine.Refined`)
    for a problem whose unknowns are nodal values on a mesh of dimension 1–3; ``base`` otherwise.
    ``correction``: ``'auto'`` (:func:`correction_kind`), ``'grid'``, ``'dense'`` or ``'span'`` (the base's
    decoder span; the grid where the base has no decoder). Where
    the operator has a modal basis (the heat scenes' modal backend) the correction also sees the
    physics' own Tikhonov estimate (:class:`pdeinv.nets.refine.SpectralFilter`, α at the noise level or at
    rounding): full rank, where ``base`` is learned from the training rows and has at most their rank."""
    from ..fem.grid import GridMap, spacing
    from ..inverse import NOISE_FREE_REL_ALPHA
    from ..physics.capabilities import modal_basis
    from .consistency import DataConsistency
    from .corrections import DenseCorrection, SpanCorrection
    from .refine import Refined, SpectralFilter

    _problem(problem)
    if not isinstance(base, nn.Module):
        raise TypeError(f"base={shown(base)} is {type(base).__name__}; expected a torch.nn.Module (the "
                        "linear network, e.g. pdeinv.nets.linear_default(problem))")
    _correction(correction)
    kind = correction_kind(problem)
    if kind is None:
        return base
    decoder = declared(base).decoder
    if (kind if correction == "auto" else correction) == "span" and decoder is not None:
        return Refined(base, correction=SpanCorrection(decoder.detach(), DENSE_HIDDEN))
    modes = modal_basis(problem.operator)  # a full-rank physics estimate as a second input, where cheap
    noise = float(problem.noise or 0.0)
    rel = max(noise, NOISE_FREE_REL_ALPHA**0.5) ** 2
    physics = None if modes is None else SpectralFilter(modes, rel)
    consistency = None if modes is None else DataConsistency(modes, rel)  # P f(y) = y to the noise
    if (kind if correction == "auto" else correction) == "dense":
        dense = DenseCorrection(problem.N, problem.operator.n_out, DENSE_HIDDEN, physics)
        return Refined(base, correction=dense, consistency=consistency)
    return Refined(base, GridMap(problem.points, spacing(problem.disc.basis.mesh)), physics=physics,
                   consistency=consistency)


def _prior_decoded(problem, rows_per_component) -> bool:
    """Whether :func:`default_model` gives ``problem`` the prior decoder at any size: a non-reversible
    operator, trained by a rule that converges (no ``rows_per_component`` cap)."""
    from ..physics.capabilities import reversible

    return rows_per_component is None and not reversible(problem.operator)


def default_size(problem) -> tuple[int, int]:
    """``(parameters + buffers, widest layer)`` of :func:`default_model`'s network for ``problem``,
    without building it (the memory guard, :func:`pdeinv.training.plan.check_training`; an upper bound:
    the decoder may keep fewer than :data:`REDUCED_K_MAX` columns); a problem
    with its own ``model_factory`` gets the dense bound ``m² + m n + n`` (an upper bound for
    the scenes' MLP)."""
    _problem(problem)
    m, n = problem.operator.n_out, problem.operator.n_in
    k = min(m, n)  # the whitening's components (:func:`whitened`)
    dense = m * k + k * n + n
    if problem.model_factory is not None:
        return dense, max(m, n)
    if max(m, n) > REDUCED_ABOVE or _prior_decoded(problem, None):
        k_in, k_out = min(REDUCED_K_IN, m), min(REDUCED_K_MAX, n)
        size = k_in * k_out + k_out + m * k_in + n * k_out + m + k_in
        # a decoder that misses the prior falls back to the modal or the whitened map (_missed_prior)
        fall = _missed_prior_size(problem, rows_per_component=1)  # the larger: a first-order rule's
        dense = max(size, fall["params"] + fall["buffers"])
    return dense + refined_size(problem), max(m, n)


def _size_arguments(problem, kind, hidden, rows_per_component):
    """:func:`network_size`'s arguments checked; ``hidden`` as widths (``()``: no MLP) or None."""
    _problem(problem)
    check_settings(rows_per_component=rows_per_component)
    if not isinstance(kind, str):
        raise ValueError(f"kind={shown(kind)} is not allowed; expected 'default', 'linear', 'whitened', "
                         "'reduced', 'modal' or 'unet' (or hidden widths for the MLP)")
    return None if hidden is None else widths(hidden)


def network_size(problem, kind: str = "default", hidden=None, rows_per_component=None) -> dict:
    """What the network of ``--net kind`` (or the MLP of ``--hidden``) for ``problem`` will hold, without
    building it: ``params`` (trained), ``buffers`` (fixed arrays: whitening basis, decoder, grid maps),
    ``build`` (bytes its construction needs on top: the prior draws and Gram matrix of
    :func:`prior_basis`), ``widest`` (its widest layer) and ``dtype_bytes``. Upper bounds (a decoder may
    keep fewer columns); the memory guard (:func:`pdeinv.training.plan.check_training`) adds the
    training state per parameter. ``kind``: 'default', 'linear', 'whitened', 'reduced', 'modal'
    (:mod:`pdeinv.nets.modal`), 'unet' (:mod:`pdeinv.nets.unet`) or 'mlp' (``hidden`` given);
    ``rows_per_component``: the rule's cap (first-order rules), which decides the default's fallback."""
    hidden = _size_arguments(problem, kind, hidden, rows_per_component)
    m, n = problem.operator.n_out, problem.operator.n_in
    itemsize = torch.finfo(DTYPE).bits // 8

    def reduced_size():
        k_in, k_out = min(REDUCED_K_IN, m), min(REDUCED_K_MAX, n)
        draws = 2 * k_out  # decoder_basis: at most 2·k_max draws, their Gram matrix, QR of N × k
        return {"params": k_in * k_out + k_out, "buffers": m * k_in + k_in + m + 1 + n * k_out,
                "build": 8 * (draws * n + draws**2 + 2 * n * k_out)}

    if kind == "unet":
        from .unet import size as unet_size

        size = unet_size(problem)  # and the prior stage's correction (refined), trained parameters too
        return {**size, "params": size["params"] + refined_size(problem), "build": 0, "dtype_bytes": 4}
    if hidden:
        from ..util.memory import network_parameters

        size = {"params": network_parameters(m, n, hidden), "buffers": 2 * m, "build": 0}
        return {**size, "widest": max(m, n, *hidden), "dtype_bytes": 4}
    if kind == "modal":
        from .modal import modal_size

        size = modal_size(problem)
        if size is None:
            raise ValueError(f"net 'modal' (--net modal) needs an operator with a spectral basis; the "
                             f"operator of problem {problem.name!r} has none (heat's modal backend has one)")
        size = {**size, "build": 0}
    elif kind == "whitened":
        size = _whitened_size(m, n, min(m, n))
    elif kind == "reduced":
        size = reduced_size()
    elif kind in ("default", "linear"):
        if problem.model_factory is not None:
            k = min(m, n)
            size = {"params": m * k + k * n + n, "buffers": 0, "build": 0}
        elif max(m, n) > REDUCED_ABOVE or _prior_decoded(problem, None):
            red, fall = reduced_size(), _missed_prior_size(problem, rows_per_component)
            # the decoder is built first; a decoder that misses the prior falls back to the whitened map
            size = {k: max(red[k], fall[k]) for k in ("params", "buffers")}
            size["build"] = red["build"]
        else:
            size = _whitened_size(m, n, min(m, n))
        if kind == "default":  # the correction (.refine): U-Net parameters (trained) and grid maps
            size["params"] += refined_size(problem)
    else:
        raise ValueError(f"kind={kind!r} is not allowed; expected 'default', 'linear', 'whitened', "
                         "'reduced', 'modal' or 'unet' (or hidden widths for the MLP)")
    return {**size, "widest": max(m, n), "dtype_bytes": itemsize}


def _missed_prior_size(problem, rows_per_component=None) -> dict:
    """``{"params", "buffers"}`` of :func:`_missed_prior` (an upper bound: the whitening's cap ignored)."""
    from .modal import modal_size

    size = modal_size(problem) if rows_per_component is None else None
    if size is not None:
        return size
    m, n = problem.operator.n_out, problem.operator.n_in
    return _whitened_size(m, n, min(m, n, FALLBACK_COMPONENTS))


def _whitened_size(m: int, n: int, k: int) -> dict:
    """The whitened map's ``{"params", "buffers", "build"}``: ``k`` components, ``m`` observations, ``n``
    unknowns; built as an identity basis and a linear layer, nothing on top."""
    return {"params": k * n + n, "buffers": m * k + k + m + 1, "build": 0}


def refined_size(problem) -> int:
    """An upper bound on what :func:`refined` adds: the U-Net's parameters and the grid maps' buffers
    (``2·N·2^dim`` weights and indices, at most ``4N`` grid points), or the dense MLP's parameters; 0
    where it adds nothing."""
    from .corrections import UNet

    kind = correction_kind(problem)  # checks the problem
    if kind is None:
        return 0
    if kind == "dense":
        widths = [problem.operator.n_out + 2 * problem.N, *DENSE_HIDDEN, problem.N]
        return sum(a * b + b for a, b in zip(widths[:-1], widths[1:], strict=True)) + 2
    if kind == "span":  # the decoder's orthonormal rows and the MLP on its coordinates
        k = min(REDUCED_K_MAX, problem.N)
        widths = [k, *DENSE_HIDDEN, k]
        return k * problem.N + sum(a * b + b for a, b in zip(widths[:-1], widths[1:], strict=True)) + 1
    dim = problem.points.shape[0]
    return sum(q.numel() for q in UNet(dim).parameters()) + 2 * problem.N * 2**dim + 4 * problem.N
