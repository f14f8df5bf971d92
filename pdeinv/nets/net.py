"""The whitened network ``x = post(body(pre(y)))`` (:class:`Net`), its bodies (:data:`BODIES`) and its
linear-in-parameters view (:class:`LinearInParameters`)
that SIP's Newton step and HIG's Kronecker step use."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch
from torch import nn

from .._checks import activation_class, float_dtype, shown, widths
from .._checks import problem as _problem
from .mlp import Residual, dense
from .protocol import Network, declared
from .whitening import Whitening, check_settings


class Net(Network):
    """``x = post(body(pre(y)))``: a fitted input transform ``pre`` (e.g.
    :class:`~pdeinv.nets.whitening.Whitening`), a trainable ``body`` and a fixed output map
    ``post`` (default: none; :class:`Decoder` in :func:`reduced`). :meth:`fit_observations`
    fits ``pre`` on training observations."""

    def __init__(self, pre: nn.Module, body: nn.Module, post: nn.Module | None = None):
        super().__init__()
        for name, part in (("pre", pre), ("body", body), ("post", post)):
            if not (isinstance(part, nn.Module) or (name == "post" and part is None)):
                allowed = "a torch.nn.Module or None" if name == "post" else "a torch.nn.Module"
                raise TypeError(f"{name}={shown(part)} is {type(part).__name__}; expected {allowed}")
        self.pre, self.body = pre, body
        self.post = nn.Identity() if post is None else post

    def fit_observations(self, y, noise: float | None = None, **settings) -> Net:
        body = self._linear_body()  # a folded input transform unfolds from it (Whitening.unfold)
        declared(self.pre).fit_observations(y, noise, **({} if body is None else {"then": body}), **settings)
        return self

    def _linear_body(self) -> nn.Linear | None:
        """The body when it is one ``nn.Linear`` (alone or in an ``nn.Sequential``), else ``None``."""
        body = self.body[0] if isinstance(self.body, nn.Sequential) and len(self.body) == 1 else self.body
        return body if type(body) is nn.Linear else None

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.post(self.body(self.pre(y)))

    def fold(self) -> bool:
        """A one-layer linear body takes in the input transform where their shapes allow
        (:meth:`~pdeinv.nets.whitening.Whitening.fold_into`): what :func:`pdeinv.save_run` writes."""
        body = self._linear_body()
        return body is not None and declared(self.pre).fold_into(body)

    @property
    def decoder(self) -> torch.Tensor | None:
        """The fixed output map's rows ``Dᵀ`` (``(k, N)``; :class:`Decoder`), ``None`` without one: the
        network's fields lie in ``span D`` whatever its body (targets and inverses work there)."""
        return declared(self.post).decoder

    def coefficients(self, y: torch.Tensor) -> torch.Tensor | None:
        """``c = body(pre(y))``, the decoder's input (``f(y) = c Dᵀ``), when the network ends in a decoder:
        a rule that works in ``span D`` (:class:`~pdeinv.SIP`'s proxy) then never forms the ``(B, N)``
        fields; ``None`` without one."""
        return None if self.decoder is None else self.body(self.pre(y))

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
#: amplitude; a heat scene's weak modes sit far below: heat_1d 0.017 in float64 against 0.040). A float64
#: product costs about twice the float32 one on CPU.
DTYPE = torch.float64


def fit_preconditioning(model: nn.Module, y, noise: float | None = None, **settings) -> nn.Module:
    """Fit ``model``'s input transform on training observations ``y`` (never on ``x``).

    Calls ``model.fit_observations(y, noise, **settings)`` as the model declares it
    (:mod:`.protocol`: :class:`Net`, :class:`MLP`); ``noise`` is the relative noise level when known
    (it sets the whitening floor); ``settings`` go to the whitening (``drop=0``: floor at the noise,
    drop nothing). A model that declares nothing is left alone.
    """
    if not isinstance(model, nn.Module):
        raise TypeError(f"model={shown(model)} is {type(model).__name__}; expected a torch.nn.Module")
    declared(model).fit_observations(y, noise, **settings)
    return model


#: bodies of the whitened networks: name -> (n_in, n_out, hidden, activation) -> module
BODIES = {
    "linear": lambda n_in, n_out, hidden, act: dense(n_in, n_out, ()),
    "mlp": dense,
    "residual": Residual,
}


def check_body(body) -> str:
    """``body`` when it names one of :data:`BODIES`, else a ``ValueError`` that lists them."""
    if not isinstance(body, str) or body not in BODIES:
        raise ValueError(f"body={shown(body)} is not allowed; expected one of {', '.join(map(repr, BODIES))}")
    return body


def whitened(body: str = "linear", hidden=(256, 256), activation=nn.Tanh, rel_floor: float | None = None,
             drop: float | str = "edge", dtype: torch.dtype = DTYPE, rows_per_component: float | None = None,
             components: int | None = None):
    """A ``model_factory``: :class:`Net` of a :class:`Whitening` and a body from :data:`BODIES`, in
    ``dtype`` (default float64: see :data:`DTYPE`). With more observations than unknowns
    (``m > N``: sensor time series) the whitening keeps the ``N`` leading components: noise-free
    observations ``y = P x`` span at most ``N`` directions, so nothing is lost, and the buffers and
    the body shrink from ``m`` to ``N`` inputs (wave_sensors_2d: 3072 → 1089). ``rows_per_component``:
    keep at most one whitened direction per that many training rows (for first-order rules,
    :class:`~pdeinv.nets.whitening.Whitening`)."""
    body = check_body(body)
    hidden, activation, dtype = widths(hidden), activation_class(activation), float_dtype(dtype)
    check_settings(rel_floor, drop, components, rows_per_component)

    def factory(problem) -> nn.Module:
        problem = _problem(problem)
        m, n = problem.operator.n_out, problem.operator.n_in
        k = min(m, n) if components is None else min(components, m, n)
        pre = Whitening(m, rel_floor, drop, components=k if k < m else None,
                        rows_per_component=rows_per_component)
        return Net(pre, BODIES[body](pre.k, n, tuple(hidden), activation)).to(dtype)

    return factory
