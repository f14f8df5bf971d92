"""Networks ``f(y; θ) ≈ x``, one family per module, and how the default was chosen.

Every head starts at zero: a random head emits components the physics cannot see
(its null space), and no update rule removes them again (x-error near 1.0 against
0.2–0.3 with a zero head on a 961-unknown heat problem). Which one a problem gets:
:mod:`.defaults`; the nonlinear correction on a grid: :mod:`.refine`; the input whitening:
:mod:`.whitening`.

Three kinds of network:

* :class:`Net` (:mod:`.net`) = a fitted input transform (:class:`~pdeinv.nets.whitening.Whitening`,
  PCA whitening of the training observations) and a body from :data:`BODIES`:
  ``linear`` (``x = A z + b``), ``mlp`` (tanh layers), ``residual`` (both, summed);
  built by :func:`whitened`, in float64 (:data:`DTYPE`). The **default** where the operator is
  reversible (the wave scenes, :func:`default_model`) up to :data:`REDUCED_ABOVE` unknowns or
  observations. It has ``min(m, N)·N + N`` parameters and an ``N × N`` whitening (heat_2d
  at n = 128: 260 M parameters), so above that, and on every other scene:
* :func:`reduced` (:mod:`.reduced`): the same :class:`Net` on the ``k_in`` leading whitened components,
  with a fixed decoder basis ``Φ`` (:class:`Decoder`, the prior's principal components) on the
  output: ``x = Φ body(z)``; its trained size does not depend on the mesh, and the prior fills
  what the observations do not see.
* :func:`modal` (:mod:`.modal`, ``--net modal``): the same :class:`Net` on the whitened coefficients of the
  operator's own modes, with those modes as its decoder, where the operator has a spectral basis (the heat
  scenes). Its bases are rebuilt from the problem, so its file holds about ``2k²`` numbers for ``k``
  modes.
* :class:`MeshUNet` (:mod:`.unet`, ``--net unet``): the SIP paper's U-Net on a grid reached through the
  finite-element interpolation, on the observations and the physics' own linear estimate, trained by the
  rules end to end; parameters independent of the mesh.
* :class:`MLP` (:mod:`.mlp`): a tanh MLP (256, 256) on per-node standardized input, what ``--method adam``
  trains (:mod:`pdeinv.methods.presets` says why: a first-order rule leaves weight on the
  trailing whitened directions, which new data amplify).

Both default networks are linear in their parameters after a fixed feature map
(:meth:`Net.linear_in_parameters`): SIP's proxy step is then a Newton step
(:meth:`Net.gauss_newton_diagonal`) and HIG has an exact Kronecker-factored step
(:mod:`pdeinv.methods.hig.kron`). The whitening is fitted by the trainer on the training observations
only (:func:`fit_preconditioning`), never on ``x``, and travels with the state dict. Why linear: with the
spectral local inverse and the curvature-normalized proxy step SIP solves the linear map's proxy exactly,
and it beats the MLPs on heat and wave alike (against best-α Tikhonov: benchmarks/notes/results-history.md).
"""

from .defaults import (
           DECODER_MAX_UNCAPTURED,
           DENSE_MAX_UNKNOWNS,
           FALLBACK_COMPONENTS,
           REDUCED_ABOVE,
           correction_kind,
           data_base,
           default_model,
           default_size,
           linear_default,
           network_size,
           refined,
           refined_size,
)
from .mlp import MLP, Residual, dense, mlp, zero_last_layer
from .modal import ModalFeatures, modal
from .net import BODIES, DTYPE, LinearInParameters, Net, fit_preconditioning, whitened
from .reduced import (
           REDUCED_K,
           REDUCED_K_IN,
           REDUCED_K_MAX,
           REDUCED_UNCAPTURED,
           Decoder,
           decoder_basis,
           prior_basis,
           reduced,
)
from .unet import MeshUNet, unet

__all__ = ["BODIES", "DECODER_MAX_UNCAPTURED", "DENSE_MAX_UNKNOWNS", "DTYPE", "FALLBACK_COMPONENTS", "MLP",
           "REDUCED_ABOVE",
           "REDUCED_K", "REDUCED_K_IN", "REDUCED_K_MAX", "REDUCED_UNCAPTURED", "Decoder",
           "LinearInParameters", "MeshUNet", "ModalFeatures", "Net", "decoder_basis",
           "Residual", "correction_kind", "data_base", "default_model", "default_size", "dense",
           "fit_preconditioning",
           "linear_default", "mlp", "modal", "network_size", "prior_basis", "reduced", "refined",
           "refined_size", "unet", "whitened", "zero_last_layer"]

#: network kinds that are not linear in their parameters (SIP takes the paper's optimizer, HIG its
#: minibatch routes: :mod:`pdeinv.methods.presets`); ``--hidden`` (the MLP) is one too
NONLINEAR_KINDS = ("unet",)
