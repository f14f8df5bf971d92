"""The one bridge from any :class:`~pdeinv.physics.LinearOperator` into torch.

``apply(op, x)`` computes ``y = P x`` row-wise for a batch-first tensor ``x`` of
shape ``(B, N)`` (or ``(N,)``). The physics runs in float64 numpy under
``no_grad``; the result comes back in ``x``'s dtype and device. An operator that
offers ``torch_forward`` (:class:`pdeinv.physics.backends.device.Placed`: a dense, modal or
SVD backend on a torch device) is applied in float64 torch on its device instead,
with no round trip through numpy.

Derivatives, all exact for the discrete map:

* reverse mode: ``x̄ = Pᵀ ȳ`` — itself a call of this bridge with ``op.T``, so
  double back-propagation (e.g. Gauss–Newton products) works too;
* forward mode (``torch.func.jvp``): ``ẏ = P ẋ`` (P is linear);
* ``torch.func.vmap``: extra batch dimensions are folded into the row batch, so
  per-sample Jacobians with ``jacrev``/``vmap`` cost one multi-column physics call.

A nonlinear :class:`~pdeinv.physics.nonlinear.Physics` (declared ``linear = False``) goes through
:class:`_Nonlinear` instead, chosen by that declaration: the input ``x`` is saved, reverse mode is
``x̄ = op.vjp(x, ȳ)`` (the exact transposed tangent at ``x``) and forward mode ``ẏ = op.jvp(x, ẋ)``.
The derivative products are not differentiated again (no double back-propagation through a
nonlinear solver: an error says so).
"""

from __future__ import annotations

import torch

from .nonlinear import Physics, is_linear


def _run(op, x: torch.Tensor) -> torch.Tensor:
    """``P x`` for a tensor of any leading shape: ``op.torch_forward`` on its device if it has one,
    else the numpy ``op.forward`` on the CPU."""
    lead = x.shape[:-1]
    on_device = op.torch_forward  # declared by a placed operator (None: numpy on the CPU)
    if on_device is not None:
        flat = x.detach().reshape(-1, x.shape[-1]).to(device=op.device, dtype=torch.float64)
        out = on_device(flat)
        return out.to(device=x.device, dtype=x.dtype).reshape(*lead, out.shape[-1])
    flat = x.detach().reshape(-1, x.shape[-1]).to(device="cpu", dtype=torch.float64)
    out = op.forward(flat.numpy())
    return torch.from_numpy(out).to(device=x.device, dtype=x.dtype).reshape(*lead, out.shape[-1])


def _rows_first(fn, in_dims, x, op):
    """A vmap rule: extra batch dimensions are folded into the row batch (one physics call)."""
    d = in_dims[0]
    if d is None:
        return fn.apply(x, op), None
    return fn.apply(x.movedim(d, 0), op), 0


class _Physics(torch.autograd.Function):
    @staticmethod
    def forward(x, op):
        return _run(op, x)

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.op = inputs[1]

    @staticmethod
    def backward(ctx, grad):
        return _Physics.apply(grad, ctx.op.T), None

    @staticmethod
    def jvp(ctx, x_dot, _):
        return _Physics.apply(x_dot, ctx.op)

    @staticmethod
    def vmap(info, in_dims, x, op):
        return _rows_first(_Physics, in_dims, x, op)


def _numpy_pair(fn, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """``fn(x, z)`` on float64 numpy rows (``x`` and ``z`` share their leading shape), back in ``z``'s
    dtype and device."""
    lead = z.shape[:-1]
    x = x.detach().expand(*lead, x.shape[-1]).reshape(-1, x.shape[-1])
    flat = z.detach().reshape(-1, z.shape[-1])
    x, flat = (a.to(device="cpu", dtype=torch.float64).numpy() for a in (x, flat))
    out = fn(x, flat)
    return torch.from_numpy(out).to(device=z.device, dtype=z.dtype).reshape(*lead, out.shape[-1])


class _Derivative(torch.autograd.Function):
    """``op.jvp(x, z)`` (``which='jvp'``) or ``op.vjp(x, z)``: a product with the tangent at ``x``,
    itself not differentiable (second derivatives of a nonlinear solver are not offered)."""

    @staticmethod
    def forward(x, z, op, which):
        return _numpy_pair(op.jvp if which == "jvp" else op.vjp, x, z)

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.op = inputs[2]

    @staticmethod
    def backward(ctx, *_):
        raise NotImplementedError(f"second derivatives through the nonlinear {ctx.op!r} are not offered "
                                  "(its vjp/jvp are not differentiated again); use a first-order method")

    @staticmethod
    def vmap(info, in_dims, x, z, op, which):
        x = x if in_dims[0] is None else x.movedim(in_dims[0], 0)
        z = z if in_dims[1] is None else z.movedim(in_dims[1], 0)
        size = info.batch_size
        x = x.expand(size, *x.shape) if in_dims[0] is None else x
        z = z.expand(size, *z.shape) if in_dims[1] is None else z
        # below the vmapped dimension the rows broadcast (jacrev: one x against many cotangents)
        x = x.reshape(size, *[1] * (z.ndim - x.ndim), *x.shape[1:])
        z = z.reshape(size, *[1] * (x.ndim - z.ndim), *z.shape[1:])
        lead = torch.broadcast_shapes(x.shape[:-1], z.shape[:-1])
        return _Derivative.apply(x.expand(*lead, x.shape[-1]), z.expand(*lead, z.shape[-1]), op, which), 0


class _Nonlinear(torch.autograd.Function):
    """``P(x)`` for a nonlinear Physics: saves ``x``; backward ``op.vjp``, forward mode ``op.jvp``."""

    @staticmethod
    def forward(x, op):
        return _run(op, x)

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.op = inputs[1]
        ctx.save_for_backward(inputs[0])
        ctx.x = inputs[0]  # forward mode reads it (save_for_forward would need a dual tensor)

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        return _Derivative.apply(x, grad, ctx.op, "vjp"), None

    @staticmethod
    def jvp(ctx, x_dot, _):
        return _Derivative.apply(ctx.x, x_dot, ctx.op, "jvp")

    @staticmethod
    def vmap(info, in_dims, x, op):
        return _rows_first(_Nonlinear, in_dims, x, op)


def apply(op: Physics, x: torch.Tensor) -> torch.Tensor:
    """``P x`` (or ``P(x)``) for a batch-first tensor, differentiable in reverse and forward mode."""
    if not isinstance(op, Physics):
        raise TypeError(f"op={op!r:.60} is {type(op).__name__}; expected a pdeinv operator (e.g. "
                        "problem.operator)")
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"x is a {type(x).__name__}; expected a torch.Tensor (use op.forward for numpy)")
    if x.ndim == 0 or x.shape[-1] != op.n_in:
        raise ValueError(f"x has shape {tuple(x.shape)}; expected (B, {op.n_in}) or ({op.n_in},)")
    if not x.is_floating_point():
        raise ValueError(f"x has dtype {x.dtype}; expected a floating-point tensor")
    return _Physics.apply(x, op) if is_linear(op) else _Nonlinear.apply(x, op)
