"""Half-inverse gradients (HIG): Schnell, Holl & Thuerey, ICLR 2022."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from ..._checks import at_least, choice, count, finite, flag, label, nonnegative, positive
from ...inverse.decoder import decoded_svd
from ...nets.protocol import declared
from ...physics.base import Matrix
from ...physics.capabilities import modal_basis
from ...physics.nonlinear import is_linear, require_linear
from ...util.memory import HIG_JACOBIAN_GB
from ..base import Rule, State, Update
from ..transforms import Add
from .kronecker import Kronecker
from .routes import JACOBIANS, ROUTES, Batch

SETTINGS = ("eta", "tau", "exponent", "route", "jacobian", "max_jacobian_gb", "gram_cond_max", "probes",
            "power_iters", "seed", "normalize")


@dataclass(frozen=True)
class HIG(Rule):
    """``Δθ = −η · V Λ^e Uᵀ g`` from the stacked Jacobian ``J = U Λ Vᵀ`` (e = ``exponent``).

    ``J`` stacks the per-sample Jacobians ``∂y_i/∂θ = P · ∂x_i/∂θ`` of network and
    physics over the batch (rows = batch × n_out, columns = trainable parameters),
    ``g`` stacks the per-sample loss gradients ``∂/∂y_i ½‖y_i − y*_i‖² = y_i − y*_i``.
    Singular values ``σ ≤ τ · σ_max`` are *dropped* (their directions get no
    update), never clamped. ``e = −½`` is the half-inverse of the paper; ``e = −1``
    with η = 1 is the Gauss–Newton step ``−J⁺ g`` (hence ``g`` is the per-sample
    residual, not divided by the batch size: GN does not depend on the loss scale).
    The direction is the step itself (:class:`~.transforms.Add`, as in the reference
    code, no optimizer); the guard's multiplier scales it.

    Routes are strategy objects chosen by table (:mod:`.hig_routes`).
    Jacobian (``jacobian=``, all with ``torch.func`` over ``functional_call``):

    * ``"forward"``: ``∂x_i/∂θ`` by ``vmap(jacrev(f))``, then ONE forward physics call
      on all ``B · n_params`` Jacobian columns;
    * ``"reverse"``: ``vmap(jacrev(P ∘ f))``, i.e. ONE adjoint physics call on
      ``B · n_out`` unit cotangents, then the network's vector-Jacobian products;
    * ``"chain"``: ``P'(x_i) · ∂x_i/∂θ`` with the physics' own per-row Jacobians
      (``op.jacobian(X)``, e.g. the Allen–Cahn heat's exact tangent factors): no physics run
      per cotangent;
    * ``"auto"``: ``"chain"`` where the physics has per-row Jacobians, else the route with fewer
      physics columns (reverse unless the network has fewer parameters than observations) —
      identical results, the physics cost differs by the factor ``n_params / n_out``.

    On a dense network (:class:`pdeinv.MLP`, :func:`pdeinv.nets.dense`, a :class:`~pdeinv.nets.Net` with
    such a body) ``J`` and ``J Jᵀ`` are built from its layer structure instead
    (:mod:`pdeinv.methods.hig.structured`, ``info["jacobian"] == "structured"``): the same ``J``,
    no ``torch.func``, and ``J Jᵀ`` at ``(B·r)²`` per hidden width instead of per parameter
    (heat_1d, MLP (64, 64), batch 32: 0.16 s per step against 1.2 s).

    Decomposition (``route=``; recorded in ``info["route"]``):

    * ``"svd"``: float64 thin SVD of ``J``;
    * ``"gram"``: float64 ``eigh(J Jᵀ) = U Λ² Uᵀ``, update ``−η Jᵀ U Λ^(e−1) Uᵀ g``
      (``V = Jᵀ U Λ⁻¹``): ~10–20× faster when rows ≪ parameters, but
      squaring doubles the condition number's exponent, so small kept σ lose
      accuracy (relative error ≈ 2e-16 · cond²);
    * ``"randomized"``: matrix-free, ``J`` is never formed: a rank-``probes``
      randomized SVD from ``jvp``/``vjp`` products with ``power_iters`` power
      iterations (:mod:`pdeinv.methods.hig.randomized`); exact when
      ``rank(J) ≤ probes``, else the step lives in the top-``probes`` singular
      subspace (``info["rank_limited"]`` says when the cap, not τ, cut the spectrum);
    * ``"last_layer"``: for a dense network (:class:`pdeinv.MLP`, :func:`pdeinv.nets.dense`, a
      :class:`~pdeinv.nets.Net` with such a body; others are refused): the exact step of its last
      ``nn.Linear`` on the hidden features (``J_LᵀJ_L = (P̂ᵀP̂) ⊗ (H̃ᵀH̃)``, :mod:`.hig_kron`'s algebra),
      ``J`` never formed; **the hidden layers take no step** (:mod:`pdeinv.methods.hig.layers`: a
      Kronecker-factored step for them diverges); τ and ``σ_max`` are the last layer's;
    * ``"auto"``: ``gram`` when rows ≤ parameters and the kept part's condition
      number ``σ_max/σ_min,kept`` is at most ``gram_cond_max`` (1e6: relative error
      ≲ 2e-4 in the smallest kept direction), else ``svd`` (recorded as
      ``"svd"``; ``info["gram_rejected"]`` says the Gram route was tried first);
      when the dense Jacobian would exceed ``max_jacobian_gb``, ``last_layer`` for a dense
      network (better than ``randomized`` at equal steps and at equal wall time,
      :mod:`pdeinv.methods.hig.layers`), else ``randomized``.

    **Compressed rows.** With a spectral basis of rank ``r < m`` (the modal heat backend, a
    compiled SVD: ``P = Out diag(g) Inᵀ`` exactly) and ``Out = Q R`` (Euclidean QR), each
    sample's Jacobian is ``∂y/∂θ = Q C ∂x/∂θ`` with ``C = R diag(g) Inᵀ`` (``r × N``); ``Q``
    has orthonormal columns, so ``J = (I ⊗ Q) J_c`` has the singular values of ``J_c`` and
    ``Uᵀ g = U_cᵀ (I ⊗ Qᵀ) g``: the same step from ``r`` rows per sample instead of ``m``
    (:func:`compress`; heat_2d: 217 of 961).

    **Kronecker** (``route="kronecker"``, and ``"auto"`` whenever the network declares it is linear
    in its parameters after a fixed feature map, :meth:`pdeinv.nets.Net.linear_in_parameters`: the
    whitened linear and the reduced default networks): ``J Jᵀ = (Z̃Z̃ᵀ) ⊗ (P̂P̂ᵀ)``, so the exact
    step needs one ``B × B`` eigendecomposition per step and the SVD of ``P̂ = P D`` once
    (:mod:`.hig_kron`); ``J`` is never formed, whatever the network's size.

    **Scale** (``normalize=True``, default): the step is multiplied by ``σ_max^-(1+e)``, so that
    it changes the residual along singular direction ``k`` by the factor ``1 − η (σ_k/σ_max)^(1+e)``:
    η = 1 solves the leading direction in one step and ``0 < η < 2`` is stable whatever the
    scale of ``P``, of the network's input and of the batch (raw, that factor is
    ``1 − η σ_k^(1+e)``, and the stable η moved with all three: on whitened inputs
    ``σ_max ≈ √B · s_max(P)``). For Gauss–Newton (``e = −1``) the factor is 1: it is scale-free.

    **Data-parallel** (:meth:`data_parallel`, what ``torchrun`` uses): on the Kronecker route the
    shards' moments are summed over the processes, so every rank takes the whole batch's exact
    step (:mod:`.hig_kron`); the Jacobian routes couple the whole stacked ``J`` and are refused.

    A route whose memory exceeds ``max_jacobian_gb`` is refused with a
    ``ValueError`` before anything is computed. The randomized probes are drawn
    from ``SeedSequence([seed, step])``, so a resumed run repeats them.
    """

    eta: float = 1.0
    tau: float = 1e-6
    exponent: float = -0.5
    route: str = "auto"
    jacobian: str = "auto"
    max_jacobian_gb: float = HIG_JACOBIAN_GB
    gram_cond_max: float = 1e6
    probes: int = 128
    power_iters: int = 1
    seed: int = 0
    normalize: bool = True
    name: str = "hig"
    #: sums numpy arrays over data-parallel processes (:meth:`data_parallel`); None: one process
    sum_over: Callable | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        label(self.name, "name")
        positive(self.eta, "eta")
        nonnegative(self.tau, "tau")
        if not self.tau < 1:
            raise ValueError(f"tau={self.tau!r} is not allowed; expected 0 <= tau < 1 "
                             "(relative to the largest singular value)")
        choice(self.route, "route", tuple(ROUTES))
        count(self.probes, "probes")
        count(self.power_iters, "power_iters", minimum=0)
        choice(self.jacobian, "jacobian", tuple(JACOBIANS))
        positive(self.max_jacobian_gb, "max_jacobian_gb")
        # accepted silently before: a seed numpy refuses at the first step, a NaN exponent (a NaN step),
        # a condition cap of 0, a truthy normalize, a sum_over that is no function
        count(self.seed, "seed", minimum=0)
        finite(self.exponent, "exponent")
        at_least(self.gram_cond_max, "gram_cond_max", 1)
        flag(self.normalize, "normalize")
        if self.sum_over is not None and not callable(self.sum_over):
            raise TypeError(f"sum_over={self.sum_over!r} is {type(self.sum_over).__name__}; expected None "
                            "or a function summing arrays over the processes (HIG.data_parallel)")

    transform = Add()

    def settings(self) -> dict:
        return {k: v for k, v in vars(self).items() if k in SETTINGS}

    def data_parallel(self, sum_over: Callable, processes: int) -> HIG:
        """This rule on one shard of ``processes``: ``sum_over(arrays) -> arrays`` sums over the
        processes (``all_reduce``); only the Kronecker route runs so (class docstring)."""
        if self.route not in ("auto", "kronecker"):
            raise ValueError(f"HIG(route={self.route!r}) cannot run on {processes} processes: its step "
                             "decomposes the Jacobian stacked over the whole batch; only the Kronecker "
                             "route (route='auto' or 'kronecker', the default networks) is data-parallel")
        return replace(self, route="kronecker", sum_over=sum_over)

    def context(self, problem, model):
        op = problem.operator
        if self.route == "kronecker":
            require_linear(op, "HIG(route='kronecker') (it factors P D once for the run)")
        kron_route = self.route in ("auto", "kronecker") and is_linear(op)
        lin = declared(model).linear_in_parameters() if kron_route else None
        if lin is None and self.sum_over is not None:
            raise ValueError(f"rule 'hig' cannot run on several processes with {type(model).__name__}: "
                             "only its Kronecker route is data-parallel, and that needs a network linear in "
                             "its parameters (the default networks); run it with one process, or use gd, "
                             "adam or sip")
        if lin is None and self.route == "kronecker":
            raise ValueError("HIG(route='kronecker') needs a network linear in its parameters after a fixed "
                             "feature map (model.linear_in_parameters(), e.g. pdeinv.nets.whitened('linear') "
                             f"or pdeinv.nets.reduced()); {type(model).__name__} does not declare one")
        kron = None if lin is None else Kronecker(lin, decoded_svd(op, lin.decoder))
        device = next(iter(model.parameters()), torch.empty(0)).device
        if kron is None and device.type != "cpu":
            raise ValueError(f"HIG's Jacobian routes decompose J with numpy on the CPU; the model is on "
                             f"{device}: use a network linear in its parameters (the default networks: "
                             "the Kronecker route runs on any device) or train on the CPU")
        return (op, *compress(op), set(), kron)  # set(): the route warnings already given in this run

    def update(self, state: State, model: torch.nn.Module, y_target: torch.Tensor,
               target: torch.Tensor | None = None) -> Update:
        op, small, Q, said, kron = state.context
        goal = y_target if target is None else target
        b = Batch.of(model, small, y_target)
        route = self._route(b, kron, said)  # the first of ROUTES' candidates within the memory budget
        return route.step(self, b, op, Q, goal, state.steps)

    def unit(self, info: dict) -> float:
        """``σ_max^-(1+e)`` with ``normalize`` (class docstring), else 1."""
        smax = info.get("sigma_max", 0.0)
        return smax ** -(1.0 + self.exponent) if self.normalize and smax > 0 else 1.0

    def _route(self, b: Batch, kron: Kronecker | None, said: set | None = None):
        """The first candidate route within ``max_jacobian_gb``; a ``ValueError`` naming them if none fits.
        A route other than the first is taken with a warning that names it (never silently: the
        last-layer route trains the last layer only), once per run (``said``: the warnings given)."""
        budget = self.max_jacobian_gb * 2**30
        first, *others = ROUTES[self.route](self, b, kron)
        for route in (first, *others):
            if route.memory(b) <= budget:
                if route is not first:
                    frozen = ("; only the last layer trains, the hidden layers stay as they are"
                              if route.name == "last_layer" else "")
                    text = (f"HIG: route {first.name!r} needs about {first.memory(b) / 2**30:.3g} GB, above "
                            f"max_jacobian_gb={self.max_jacobian_gb:g}; taking the {route.describe(b)}"
                            + frozen)
                    if said is None or text not in said:
                        warnings.warn(text, stacklevel=2)
                    if said is not None:
                        said.add(text)
                return route
        also = "".join(f" (the {r.describe(b)})" for r in others)
        raise ValueError(
            f"HIG Jacobian of {b.rows} rows (batch {b.y.shape[0]} × {b.op.n_out} observations) × "
            f"{b.n_params} parameters needs about {first.memory(b) / 2**30:.3g} GB with route "
            f"{first.name!r}{also}, above max_jacobian_gb={self.max_jacobian_gb:g}; use a smaller "
            "batch_size or network (fewer parameters), or raise max_jacobian_gb")


def compress(op):
    """``(C, Q)`` with ``P = Q C`` exactly and ``QᵀQ = I`` (class docstring), as ``(Matrix(C), Q)``; or
    ``(op, None)`` when ``op`` has no spectral basis or its rank is not below its row count."""
    basis = modal_basis(op)
    if basis is None or len(basis.g) >= op.n_out:
        return op, None
    Q, R = np.linalg.qr(basis.out)
    return Matrix((R * basis.g) @ basis.In.T), torch.from_numpy(Q)
