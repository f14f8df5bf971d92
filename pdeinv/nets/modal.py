"""The linear map in the operator's own modes (:func:`modal`), for operators with a spectral basis.

Where the operator is diagonal in a basis of modes, ``P x = Σ_k g_k ⟨φ_k, x⟩_M ψ_k`` (the modal heat
backend, :func:`pdeinv.physics.capabilities.modal_basis`: ``proj`` gives the coefficients ``⟨ψ_k, y⟩``,
``synth`` the fields ``φ_k``), the observations decide a field only along the modes whose gain ``g_k`` stands
above float64 rounding of ``y``: those the spectral basis keeps. The network

    f(y) = Q (W z(y) + b),   z(y) = whiten(⟨ψ_k, y⟩_k),   Φ = Q R,

maps those modes' coefficients, whitened on the training observations (never ``x``:
:class:`~pdeinv.nets.whitening.Whitening` in ``k`` dimensions), through a trained ``k × k`` matrix ``W``
and bias ``b`` to coefficients in ``Q``, an orthonormal basis of the modes' span ``Φ`` (``φ_k`` are
M-orthonormal, not orthonormal in ℓ²: on heat_plate ``cond(ΦᵀΦ) = 9``). Both bases orthonormal, the rules'
full-batch proxy ``½‖f(y) − x̃‖²`` has the identity Hessian in ``(W, b)`` and SIP's step solves it (with
``Φ`` itself, 30 SIP steps left heat_plate's box scene at y-error 4e-3; with ``Q`` 3e-13). It is a
:class:`~pdeinv.nets.net.Net` linear in its parameters with the fixed decoder ``Q`` (SIP solves in its span,
HIG takes the Kronecker route). Its bases are rebuilt from the problem, not saved, and
:func:`pdeinv.save_run` folds the whitening into ``W`` (:meth:`~pdeinv.nets.whitening.Whitening.fold_into`):
``model.pt`` holds about ``k²`` numbers however large the mesh, where the whitened map holds two ``N × k``
arrays.
The field's part along modes the observations do not decide is left at 0, as by every linear estimate that
the data alone decide; the prior stage adds it.
"""

from __future__ import annotations

import numpy as np
import torch

from .._checks import float_dtype, matrix
from .._checks import problem as _problem
from .mlp import dense
from .net import DTYPE, Net
from .protocol import Network
from .reduced import Decoder
from .whitening import Whitening, check_settings


class ModalFeatures(Network):
    """``z(y) = whiten(y @ proj)`` (module docstring): ``proj`` ``(m, k)`` is rebuilt from the problem (not
    saved); the whitening of the ``k`` coefficients (:class:`~pdeinv.nets.whitening.Whitening`) is fitted on
    training observations and saved (``k² + 2k`` numbers)."""

    def __init__(self, proj: np.ndarray, rows_per_component: float | None = None):
        super().__init__()
        proj = np.asarray(matrix(proj, "proj"), dtype=float)
        self.register_buffer("proj", torch.as_tensor(proj), persistent=False)
        self.whitening = Whitening(self.proj.shape[1], rows_per_component=rows_per_component)

    @property
    def k(self) -> int:
        return self.whitening.k

    @property
    def info(self) -> dict:
        return self.whitening.info

    @torch.no_grad()
    def fit_observations(self, y, noise=None, then=None, **settings) -> ModalFeatures:
        c = torch.as_tensor(y, dtype=self.proj.dtype, device=self.proj.device) @ self.proj
        self.whitening.fit_observations(c.cpu(), noise, then=then, **settings)
        return self

    def fold_into(self, linear) -> bool:
        return self.whitening.fold_into(linear)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.whitening(y.to(self.proj.dtype) @ self.proj)


def visible_modes(problem):
    """``(proj, synth)`` of the operator's modes (those its spectral basis keeps: gains above rounding), or
    ``None`` where the operator has no spectral basis."""
    from ..physics.capabilities import modal_basis

    _problem(problem)
    modes = modal_basis(problem.operator)
    if modes is None:
        return None
    return np.asarray(modes.proj), np.asarray(modes.synth)


def modal(dtype: torch.dtype = DTYPE, rows_per_component: float | None = None):
    """A ``model_factory``: the linear map in the operator's visible modes (module docstring); a
    ``ValueError`` where the operator has no spectral basis. ``rows_per_component``: the whitening's cap
    for first-order rules (:class:`~pdeinv.nets.whitening.Whitening`)."""
    dtype = float_dtype(dtype)
    check_settings(rows_per_component=rows_per_component)

    def build(problem) -> Net:
        _problem(problem)
        found = visible_modes(problem)
        if found is None:
            raise ValueError(f"net 'modal' (--net modal) needs an operator with a spectral basis; the "
                             f"operator of problem {problem.name!r} has none (heat's modal backend has one)")
        proj, synth = found
        pre = ModalFeatures(proj, rows_per_component)
        q = np.linalg.qr(synth)[0]  # the span's orthonormal basis (module docstring)
        return Net(pre, dense(pre.k, pre.k, ()), Decoder(torch.as_tensor(q), persistent=False)).to(dtype)

    return build


def modal_size(problem) -> dict | None:
    """``{"params", "buffers"}`` of :func:`modal`'s network without building it, ``None`` without a spectral
    basis: ``k² + k`` trained, the whitening's ``k² + 2k`` (the bases are rebuilt)."""
    found = visible_modes(problem)
    if found is None:
        return None
    k = found[0].shape[1]
    return {"params": k * k + k, "buffers": k * k + 2 * k + 1}
