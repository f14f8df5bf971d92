"""The physics seen through a fixed decoder, and the local inverse that stays in the decoder's span.

A network whose output is ``x = D c`` for a fixed decoder ``D`` (``N × k``: :func:`pdeinv.nets.reduced`,
the prior's leading principal components) can only produce fields in ``span D``. Its observations are
``y = P D c = P̂ c`` with ``P̂ = P D`` (``m × k``), whose thin SVD ``P̂ = Q diag(s) Vᵀ`` costs ``k``
forward calls and one small SVD (:func:`decoded_svd`; HIG's Kronecker route uses the same factor).

:class:`DecoderTikhonov` is the regularized solve *in that span*,

    x̃ = D argmin_c ‖P̂ c − y‖² + α‖c‖² = D V diag(s / (s² + α)) Qᵀ y,

with a rounding-level ``α = rel_alpha · s_max²`` (1e-24: singular values resolved to 1e-12 of the
largest, so float64 rounding in ``y`` (ε ≈ 2e-16 of its norm) reaches a coefficient amplified by at
most ``ε/(2·1e-12) ≈ 1e-4``; noisy observations are denoised before, by the trainer's target,
:mod:`pdeinv.targets`, in the same basis). Measured (SIP, CLI defaults, noise-free, rel_alpha
1e-16 → 1e-24): heat_2d 0.0076 → 0.0016, heat_3d 0.0122 → 0.0033 (1e-20: 0.0062; 0, i.e. every
singular value above the SVD's rounding: 0.0047, rounding amplified), heat_1d 0.0146 → 0.0040,
heat_sensors_2d 0.0108 → 0.0039, heat_sensors_3d 0.048 → 0.027, heat_cavity_3d 0.0099 → 0.0080,
wave_sensors_2d 2.3e-5 both.
SIP with it converges to the least-squares fit *through the physics* inside the decoder's span:
the prior's principal components then extrapolate into modes the observation barely sees, where the
full-space inverse followed by SIP's Euclidean proxy projects a field that has nothing there.
Measured in closed form (1024 training observations, 128 test pairs; projection of the full-space
inverse → this): heat_plate noise-free 0.0519 → 0.0107 (best-α Tikhonov 0.0615), at 1 % noise with
the Wiener target 0.1406 → 0.1255 (0.1405); wave_sensors_2d 9.8e-5 → 4.4e-5 and 0.00285 → 0.00258.
Trained (``pdeinv train SCENE``, CLI defaults, SIP 30 full-batch steps): heat_plate 0.0496 → 0.0101
and 0.142 → 0.127 at 1 %; wave_sensors_2d 4.4e-5 (unchanged) and 0.00277 → 0.00256.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._checks import batch
from ._inputs import out

#: α relative to s_max² of the decoded physics (module docstring)
REL_ALPHA = 1e-24


class DecodedSVD(NamedTuple):
    """``P̂ = P D = Q diag(s) Vᵀ`` (thin SVD, zero singular values dropped)."""

    Q: np.ndarray  # (m, r)
    s: np.ndarray  # (r,)
    V: np.ndarray  # (k, r)


def decoded_svd(op, decoder) -> DecodedSVD:
    """``P̂``'s thin SVD from ``k`` forward calls; ``decoder``: the rows ``Dᵀ`` (``(k, N)``, numpy or
    torch), ``None`` for the identity (``N`` calls). Computed once per operator and decoder object (the
    trainer's target, SIP's inverse and HIG's step all ask for it)."""
    cache = op.__dict__.setdefault("_decoded_svd", {}) if hasattr(op, "__dict__") else {}
    key = id(decoder)
    if key not in cache:  # the entry keeps the decoder alive: its id stays unique
        cache[key] = (decoder, _decoded_svd(op, decoder))
    return cache[key][1]


def _decoded_svd(op, decoder) -> DecodedSVD:
    P_hat = np.asarray(op.forward(decoded_rows(decoder, op.n_in)), dtype=float).T  # (m, k)
    Q, s, Vt = np.linalg.svd(P_hat, full_matrices=False)
    keep = s > s[0] * max(P_hat.shape) * np.finfo(float).eps if s.size and s[0] > 0 else np.zeros(0, bool)
    return DecodedSVD(Q[:, keep], s[keep], Vt[keep].T)


class DecoderTikhonov:
    """``(y, x0) -> x̃``: the Tikhonov solve in the decoder's span (module docstring); ``x0`` is
    unused (the map is linear in ``y``)."""

    def __init__(self, op, decoder, rel_alpha: float = REL_ALPHA):
        from .._checks import positive

        self.rel_alpha = positive(rel_alpha, "rel_alpha")
        self.svd = decoded_svd(op, decoder)
        self.rows = decoded_rows(decoder, op.n_in)
        s = self.svd.s
        self.filter = s / (s**2 + self.rel_alpha * (s[0] ** 2 if s.size else 0.0))

    def __call__(self, y, x0=None) -> np.ndarray:
        Y, single = batch(y, len(self.svd.Q), "y")
        c = ((Y @ self.svd.Q) * self.filter) @ self.svd.V.T
        return out(c @ self.rows, single)


def decoded_rows(decoder, n: int) -> np.ndarray:
    """The decoder's rows ``Dᵀ`` as float64 numpy (the identity for ``None``)."""
    if decoder is None:
        return np.eye(n)
    return np.asarray(decoder.detach().cpu().double().numpy() if hasattr(decoder, "detach") else decoder,
                      dtype=float)
