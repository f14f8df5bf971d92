"""Matrix-free HIG direction from a randomized truncated SVD (Halko, Martinsson & Tropp 2011).

The stacked Jacobian ``J = ∂y/∂θ`` (rows ``B·n_out``, columns ``n_params``) is never
formed. Only products are used, in float64 (a float64 copy of the parameters, so
the small singular values HIG keeps are not lost to float32 rounding):

* ``J V``  for ``l`` probe vectors at once: forward mode, ``torch.func.jvp`` through
  network and physics, ``vmap``-ed over the probes (one multi-column physics call);
* ``Jᵀ U`` for ``l`` cotangents at once: one ``torch.func.vjp``, ``vmap``-ed (one
  multi-column adjoint call).

Range finder with ``q`` power iterations: ``Ω`` Gaussian ``n_params × l``,
``Q = orth(J Ω)``, then ``q`` times ``Q = orth(J (Jᵀ Q))``, orthonormalizing only the
short ``rows × l`` side (a QR of the ``n_params × l`` side cost more than the products).
A power step squares the spread of the singular values, so the weakest kept
directions carry a relative rounding error of about ``1e-16·cond²``: against the
exact SVD route the step agreed to 4e-10 at ``cond ≈ 1e6`` (``tests/test_hig_randomized.py``).

Cost (heat_2d, default MLP with 559 041 parameters, batch 32, one thread): about
2 s per step with 64 probes and 9 s with 128 (one power iteration); the dense
Jacobian there (30 752 × 559 041) would need about 190 GB.
With ``Bᵀ = Jᵀ Q`` (``n_params × l``) and ``B Bᵀ = Z S² Zᵀ`` (a small ``eigh``),
``J ≈ Q B = (Q Z) S Wᵀ`` with ``W = Bᵀ Z S⁻¹``. Over the kept singular values
(``σ > τ·σ_max``) the HIG step is

    Δθ = −η W S^e (Q Z)ᵀ g = −η Bᵀ Z S^(e−1) Zᵀ Qᵀ g.

It is exact (to rounding) when ``rank(J) ≤ l``; otherwise the update lives in the
top-``l`` singular subspace, whose accuracy the power iterations improve (the error
factor falls like ``(σ_(l+1)/σ_k)^(2q+1)``). Memory: about three ``n_params × l``
float64 arrays at the peak, instead of ``B·n_out × n_params``, and the products' own working set: each
probe carries the batch's activations through the network, so the probes go through ``vmap`` in chunks
of at most :data:`ACTIVATION_BYTES` of activations (:func:`activation_bytes`, :func:`memory_bytes`).
"""

from __future__ import annotations

import numpy as np
import torch
from torch.func import jvp, vjp, vmap

from ...physics.bridge import apply

#: float64 n_params × probes arrays alive at the peak (a product, its transposed copy, Bᵀ)
ARRAYS = 3

#: activations of the probes ``vmap`` carries at once: more probes than fit go through in chunks (a
#: U-Net on a 64² grid holds ~600 MB per probe for a batch of 32; all 128 probes at once needed >24 GB)
ACTIVATION_BYTES = 2**30

#: copies of the saved activations a probe's product holds: the tangents (jvp) or the cotangents (vjp)
#: beside the primal's (measured peaks: 1.85–1.95× the saved bytes, U-Nets on 16² to 64² grids)
COPIES = 2


def activation_bytes(batch) -> int:
    """What the float64 forward of the batch through network and physics saves for the backward (bytes,
    each saved tensor once): held once by the ``vjp`` for the whole step, and :data:`COPIES` times by
    each probe in a ``vmap``-ed product."""
    b = batch.double()
    seen, total = set(), [0]

    def pack(t):
        key = (t.data_ptr(), t.numel(), t.dtype)
        if key not in seen:
            seen.add(key)
            total[0] += t.numel() * t.element_size()
        return t

    params = {n: p.detach().requires_grad_(True) for n, p in b.params.items()}
    with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t), torch.enable_grad():
        apply(b.op, b.f(params, b.y))
    return int(total[0])


def chunk(probes: int, activations: int) -> int:
    """Probes per ``vmap`` call: as many as keep their :data:`COPIES` of ``activations`` under
    :data:`ACTIVATION_BYTES`."""
    return int(max(1, min(probes, ACTIVATION_BYTES // max(COPIES * activations, 1))))


def memory_bytes(n_params: int, probes: int, rows: int, activations: int = 0) -> int:
    """Peak bytes of the randomized route: ``ARRAYS`` float64 ``n_params × l`` blocks, ``rows × l``, the
    ``vjp``'s saved ``activations`` and one chunk of probes' copies of them (:func:`chunk`; measured
    peaks within 5 % of this, U-Nets on 64² grids)."""
    per_probe = COPIES * activations
    return 8 * probes * (ARRAYS * n_params + 2 * rows) + activations + chunk(probes, activations) * per_probe


def _orth(A: torch.Tensor) -> torch.Tensor:
    return torch.linalg.qr(A, mode="reduced")[0]


def randomized_direction(batch, g, probes: int, power_iters: int, tau: float, exponent: float, eta: float,
                         seed: int, activations: int | None = None):
    """``(Δθ, info)``: the HIG step from a rank-``probes`` randomized SVD (module docstring).

    ``batch`` is the routes' view of the model and the batch (:class:`~.hig_routes.Batch`, taken
    in float64); ``g`` is the stacked residual ``(B·n_out,)``; ``Δθ`` is flat, in the order of the
    model's trainable parameters. ``seed`` fixes ``Ω`` (a resumed run repeats it). ``activations``:
    :func:`activation_bytes` of the batch (``None``: measured here), which sets the probes per ``vmap``.
    """
    b = batch.double()
    params, op, names = b.params, b.op, list(b.params)
    shapes = [params[n].shape for n in names]
    sizes = [params[n].numel() for n in names]
    n_params = sum(sizes)
    B = b.y.shape[0]
    rows = B * op.n_out
    probes = min(probes, rows, n_params)
    at_once = chunk(probes, activation_bytes(batch) if activations is None else activations)

    def y_of(p):
        return apply(op, b.f(p, b.y))

    def unflat(V):  # (l, n_params) -> {name: (l, *shape)}
        parts = torch.split(V, sizes, dim=1)
        return {n: t.reshape(V.shape[0], *s) for n, t, s in zip(names, parts, shapes, strict=True)}

    def J_times(V):  # (n_params, l) -> (rows, l)
        out = vmap(lambda v: jvp(y_of, (params,), (v,))[1], chunk_size=at_once)(unflat(V.T.contiguous()))
        return out.reshape(V.shape[1], rows).T

    _, pull = vjp(y_of, params)

    def JT_times(U):  # (rows, l) -> (n_params, l)
        (grads,) = vmap(pull, chunk_size=at_once)(U.T.reshape(U.shape[1], B, op.n_out).contiguous())
        return torch.cat([grads[n].reshape(U.shape[1], -1) for n in names], 1).T

    omega = torch.from_numpy(np.random.default_rng(seed).standard_normal((n_params, probes)))
    Q = _orth(J_times(omega))
    del omega
    for _ in range(power_iters):
        Q = _orth(J_times(JT_times(Q)))
    Bt = JT_times(Q)  # Jᵀ Q, (n_params, l)
    lam2, Z = np.linalg.eigh((Bt.T @ Bt).numpy())
    s = np.sqrt(lam2.clip(min=0))
    keep = (s > tau * s.max()) & (s > 0)
    Zk, sk = Z[:, keep], s[keep]
    coef = Zk @ (sk ** (exponent - 1) * (Zk.T @ (Q.T @ g.double()).numpy()))
    delta = -eta * (Bt @ torch.from_numpy(coef))
    info = dict(route="randomized", rank=int(keep.sum()), probes=probes, power_iters=power_iters,
                chunk=at_once,
                cond=float(s.max() / sk.min()), sigma_max=float(s.max()),
                # σ_min of the sketch above τ·σ_max: the rank cap, not τ, cut the spectrum
                rank_limited=bool(keep.all() and probes < min(rows, n_params)))
    return delta, info
