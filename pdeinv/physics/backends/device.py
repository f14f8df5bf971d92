"""Physics on a torch device: the compiled backends' matmuls done by torch where the data lives.

A dense, modal or SVD backend applies ``P`` by matrix products (:mod:`.compiled`):

* dense: forward ``X Pᵀ``, adjoint ``R P``;
* spectral (modal heat, SVD), ``P = out diag(g) Inᵀ``: forward ``((X In) g) outᵀ``,
  adjoint ``((R out) g) Inᵀ``.

:class:`Placed` keeps a float64 torch copy of those factors on one device and does the
same products there, forward and adjoint (its ``.T`` is placed too, so back-propagation and
double back-propagation stay on the device): no round trip through numpy. The autograd
bridge (:mod:`pdeinv.physics.bridge`) uses ``torch_forward`` whenever an operator offers it.
Everything else (``forward``/``adjoint`` on numpy arrays, capabilities such as ``modes``,
``output_space``, ``final_state``) is the wrapped operator's own. Sparse time stepping has
no factors and stays on the CPU: :func:`placed` leaves such operators alone and the bridge
moves the data to the CPU and back. (cholespy's CUDA sparse Cholesky could move stepping to
the GPU too; not built.)

:func:`resolve` turns ``device=`` / ``--device`` into a ``torch.device``, refusing one that
is unknown or not available here.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..base import LinearOperator
from ..capabilities import Spectral
from .compiled import Dense

__all__ = ["Placed", "factors", "placed", "resolve"]


def resolve(device) -> torch.device:
    """``device`` as a ``torch.device`` that exists on this machine (``ValueError`` otherwise)."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError, ValueError):
        raise ValueError(f"device {device!r} is not a torch device; "
                         "allowed: 'cpu', 'cuda', 'cuda:N'") from None
    if dev.type == "cpu":
        if dev.index not in (None, 0):  # torch takes cpu:1 and runs on the one CPU device
            raise ValueError(f"device {device!r} is not supported; allowed: 'cpu', 'cuda', 'cuda:N'")
        return dev
    if dev.type != "cuda":
        raise ValueError(f"device {device!r} is not supported; allowed: 'cpu', 'cuda', 'cuda:N'")
    if not torch.cuda.is_available():
        raise ValueError(f"device {device!r}: CUDA is not available here (torch {torch.__version__}, "
                         f"CUDA build {torch.version.cuda or 'none'}); allowed here: 'cpu'")
    if dev.index is not None and dev.index >= torch.cuda.device_count():
        raise ValueError(f"device {device!r}: there are {torch.cuda.device_count()} CUDA devices; "
                         f"allowed: cuda:0 … cuda:{torch.cuda.device_count() - 1}")
    return dev


class _Dense:
    """forward ``X Pᵀ``, adjoint ``R P``."""

    def __init__(self, P, PT):
        self.P, self.PT = P, PT

    def forward(self, X):
        return X @ self.PT

    def adjoint(self, R):
        return R @ self.P

    @property
    def T(self):
        return _Dense(self.PT, self.P)


class _Spectral:
    """``P = out diag(g) Inᵀ``: forward ``((X In) g) outᵀ``, adjoint ``((R out) g) Inᵀ``."""

    def __init__(self, In, g, out):
        self.In, self.g, self.out = In, g, out

    def forward(self, X):
        return ((X @ self.In) * self.g) @ self.out.T

    def adjoint(self, R):
        return ((R @ self.out) * self.g) @ self.In.T

    @property
    def T(self):
        return _Spectral(self.out, self.g, self.In)


def _kind(op):
    """The torch applier class for ``op``'s compiled backend (dense or spectral), or None (stepping)."""
    backend = op.backend
    return _Dense if isinstance(backend, Dense) else _Spectral if isinstance(backend, Spectral) else None


def factors(op, device) -> _Dense | _Spectral | None:
    """``op``'s compiled backend as torch float64 factors on ``device``, or None (time stepping)."""
    kind = _kind(op)
    if kind is None:
        return None
    b = op.backend
    arrays = (b.P, b.PT) if kind is _Dense else (b.In, b.g, b.out)
    return kind(*(torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64, device=device)
                  for a in arrays))


class Placed(LinearOperator):
    """``op`` with its matmuls on ``device`` (module docstring); ``ValueError`` if ``op`` has no
    dense, modal or SVD backend."""

    def __init__(self, op, device, _apply=None):
        self.op, self.device = op, torch.device(device)
        self.apply = _apply if _apply is not None else factors(op, self.device)
        if self.apply is None:
            raise ValueError(f"{type(op).__name__} has no dense, modal or SVD backend to place on "
                             f"{self.device}; time stepping runs on the CPU")
        self.n_in, self.n_out = op.n_in, op.n_out

    def torch_forward(self, X: torch.Tensor) -> torch.Tensor:
        """``P X`` row-wise on ``self.device`` (float64 ``(B, n_in)`` there)."""
        return self.apply.forward(X)

    def _forward(self, X):
        return self.op.forward(X)

    def _adjoint(self, R):
        return self.op.adjoint(R)

    @property
    def T(self) -> Placed:
        return Placed(self.op.T, self.device, self.apply.T)

    # the declared capabilities (pdeinv.physics.capabilities) are the operator's own
    output_space = property(lambda self: self.op.output_space)
    modes = property(lambda self: self.op.modes)
    mass = property(lambda self: self.op.mass)
    backend = property(lambda self: self.op.backend)
    reversible = property(lambda self: self.op.reversible)
    max_gain_squared = property(lambda self: self.op.max_gain_squared)
    kind = property(lambda self: self.op.kind)

    def stepping(self):
        return self.op.stepping()

    def final_state(self, U0, C0=None):
        return self.op.final_state(U0, C0)

    def reverse(self, UT, CT):
        return self.op.reverse(UT, CT)

    def __repr__(self):
        return f"Placed({self.op!r}, {str(self.device)!r})"


def placed(problem, device):
    """``problem`` with its operator :class:`Placed` on ``device``: a copy when ``device`` is not the
    CPU and the operator has factors, else ``problem`` itself (numpy on the CPU is the default)."""
    device = torch.device(device)
    if device.type == "cpu" or _kind(problem.operator) is None:
        return problem
    return dataclasses.replace(problem, operator=Placed(problem.operator, device))
