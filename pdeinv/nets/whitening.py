"""Data-driven preconditioning of a network's input: PCA whitening fitted on training observations.

Observations of an ill-conditioned physics are as ill-conditioned as the physics:
on heat_2d the covariance of ``y`` spans about ten orders of magnitude, so a
per-node standardization leaves the network's *input* as badly scaled as ``P``.
:class:`Whitening` fits, on the training observations only (never on ``x``),

    C = Ȳᵀ Ȳ / (n − 1) = U diag(λ) Uᵀ        (Ȳ the centred observations; thin SVD of Ȳ)

and maps an observation to

    z = D Uᵀ (y − μ),    D_i = 1/√max(λ_i, f)   if λ_i ≥ d,  else 0.

**Floor ``f``** (the smallest variance given unit scale):

* noise level known (relative level ``δ`` of :func:`pdeinv.problem.sampling.add_noise`):
  ``f = σ²`` with ``σ² = δ²/(1+δ²) · mean(y²)``, the variance white noise adds
  to *every* direction; a direction with ``λ_i ≈ σ²`` is mostly noise and is not
  blown up to unit scale;
* otherwise relative: ``f = rel_floor · max λ``. By default (``rel_floor=None``) from the
  precision of the transform's buffers: in float64 no floor beyond the numerical rank cut below
  (every resolved direction gets unit scale; the default networks are float64), in float32
  ``1e-10`` (amplitudes down to 1e-5 of the largest; float32 inputs keep ~6e-8 of it).
  Why no floor in float64: a noise-free scene's information sits in directions of tiny
  variance (heat: weak modes, 1e-20 of the largest; wave: the modes with cos(ωT) ≈ 0), and a
  direction below the floor learns ``λ/f`` times slower.

**Drop ``d``** (directions removed, ``D_i = 0``): the numerical rank cut
``d = (n·eps)²·max λ`` always (with fewer samples than observations, the
directions the data never visited are dropped instead of amplified), and with a
known noise level also ``d = drop·σ²``. The default ``drop="edge"`` is the upper
edge of the Marchenko–Pastur law, ``(1 + √(m/(n−1)))²``: the largest sample
variance pure white noise produces in ``n`` samples of ``m`` components, so every
direction below it is indistinguishable from noise (keeping them all lets SIP fit the noise, which no
stopping rule undoes). ``drop=0`` keeps all.
The cut scales with the ``n`` training rows, not with the mesh: the covariance is estimated from ``n``
samples whatever ``m`` is (a cut in ``max(n, m)`` would drop a fine mesh's resolved directions).

**Components ``k``** (optional): keep only the ``k`` leading directions, ``z = D_k U_kᵀ (y − μ)``
of length ``k``. The buffers are then ``(m, k)`` instead of ``(m, m)`` (at ``m`` = 16 129, the
heat_2d mesh at n = 128: 16.5 MB against 1.04 GB in float32), and a network on ``z`` has a size
independent of ``m`` (:func:`pdeinv.nets.reduced`).

**Rows per component ``r``** (optional): keep at most ``n // r`` leading directions of ``n``
training rows (the rest get ``D_i = 0``). For networks trained by first-order rules (GD, Adam):
with ``k`` directions fitted on ``n`` rows the sample covariance's smallest eigenvalues are about
``(1 − √(k/n))²`` of the true ones (Marchenko–Pastur), so on new data the trailing whitened
coordinates are that much larger than on the training rows, and whatever weight an unconverged
rule left on them is amplified (``k ≈ n``: without bound). ``r = 8`` bounds the factor to
``1/(1 − √(1/8))² ≈ 2.4`` in variance (Adam on wave_sensors_2d: x-error 0.0047 with it, 0.51 without).
SIP and HIG solve their linear problems exactly and keep every direction.

The transform has fixed shapes ``(m,)`` and ``(m, k)`` whatever the data, so a
fitted model loads into a fresh one; the buffers ``mean``, ``basis``, ``gain``
travel with the state dict (checkpoints, ``model.pt``) and ``fitted`` says whether
:meth:`fit` ran. Cost: one ``(B, m) × (m, k)`` product per batch.
"""

from __future__ import annotations

from numbers import Integral, Real

import numpy as np
import torch

from .._checks import count, shown
from ..inverse.noise import noise_variance
from .protocol import Network

#: default relative floor without a noise level, by the dtype of the buffers (module docstring;
#: float64: none beyond the numerical rank cut)
REL_FLOORS = {torch.float64: 0.0, torch.float32: 1e-10}
#: the float32 floor (kept for code that imports the name)
REL_FLOOR = REL_FLOORS[torch.float32]


def check_settings(rel_floor=None, drop="edge", components=None, rows_per_component=None) -> None:
    """A ``ValueError`` naming the first of :class:`Whitening`'s settings that is not allowed; the
    factories that build one (:func:`~pdeinv.nets.whitened`, :func:`~pdeinv.nets.reduced`,
    :func:`~pdeinv.nets.modal`) call it when they are made, not when they build."""
    r = rows_per_component
    if r is not None and (isinstance(r, bool) or not isinstance(r, Real) or not r >= 1 or not np.isfinite(r)):
        raise ValueError(f"rows_per_component={shown(r)} is not allowed; expected a number >= 1 or None")
    if components is not None and (isinstance(components, bool) or not isinstance(components, Integral)
                                   or components < 1):
        raise ValueError(f"components={shown(components)} is not allowed; expected an integer >= 1 or None")
    number = isinstance(rel_floor, Real) and not isinstance(rel_floor, bool)
    if rel_floor is not None and not (number and rel_floor > 0 and np.isfinite(rel_floor)):
        raise ValueError(f"rel_floor={shown(rel_floor)} is not allowed; expected a number > 0 or None")
    if not (isinstance(drop, str) and drop == "edge") and not (
            isinstance(drop, Real) and not isinstance(drop, bool) and drop >= 0 and np.isfinite(drop)):
        raise ValueError(f"drop={shown(drop)} is not allowed; expected 'edge' or a number >= 0")


class Whitening(Network):
    """``z = D Uᵀ (y − μ)`` fitted by :meth:`fit` on training observations (module docstring)."""

    def __init__(self, m: int, rel_floor: float | None = None, drop: float | str = "edge",
                 components: int | None = None, rows_per_component: float | None = None):
        super().__init__()
        m = count(m, "m")
        check_settings(rel_floor, drop, components, rows_per_component)
        r = rows_per_component
        self.rows_per_component = None if r is None else float(r)
        self.m, self.drop = m, drop
        self.rel_floor = None if rel_floor is None else float(rel_floor)
        self.k = self.m if components is None else min(int(components), self.m)
        self.register_buffer("mean", torch.zeros(m))
        self.register_buffer("basis", torch.eye(m, self.k))
        self.register_buffer("gain", torch.ones(self.k))
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool))
        self._ready = False
        self.info: dict = {}

    @torch.no_grad()
    def fit(self, y, noise: float | None = None, drop: float | str | None = None) -> Whitening:
        """Fit μ, U, D on observations ``y`` ``(n, m)``; ``noise`` is the relative level if known;
        ``drop`` overrides the constructor's for this fit (0: floor at σ² but drop nothing)."""
        if self.folded:  # its D Uᵀ lives in the next layer's weights: refitting would change the function
            return self  # (unless that layer is given: fit_observations(then=), unfold)
        y = np.asarray(torch.as_tensor(y).detach().cpu().double())
        if y.ndim != 2 or y.shape[1] != self.m:
            raise ValueError(f"whitening: observations of shape {y.shape}; expected (n, {self.m})")
        n = y.shape[0]
        if n < 2:
            raise ValueError(f"whitening needs at least 2 observations to fit a covariance; got {n}")
        if not np.isfinite(y).all():
            bad = int((~np.isfinite(y)).sum())
            raise ValueError(f"whitening: the observations hold {bad} NaN/Inf values; clean the data first")
        mu = y.mean(0)
        _, s, Vt = np.linalg.svd(y - mu, full_matrices=False)  # C = V diag(s²/(n−1)) Vᵀ
        if Vt.shape[0] < self.k:  # fewer samples than directions kept: the directions the data never
            # visited have λ = 0 and get gain 0 below, so their basis columns are never seen: zeros. An
            # orthonormal completion by QR took 10 s of heat_3d n=16's set-up (3 375 × 3 072) for nothing
            Vt = np.vstack([Vt, np.zeros((self.k - Vt.shape[0], self.m))])
        Vt = Vt[: self.k]
        lam = np.zeros(self.k)
        lam[: min(s.size, self.k)] = s[: self.k] ** 2 / (n - 1)
        if not lam[0] > 0:
            raise ValueError("the training observations do not vary (zero covariance): every y is the same, "
                             "so there is nothing to learn from them (does the physics leave anything to "
                             "observe, e.g. a κT that lets every field decay to 0? does the sampler return "
                             "one field?)")
        cut = (n * np.finfo(float).eps) ** 2 * lam[0]  # the SVD's numerical rank, from the n rows
        if noise:
            sigma2 = noise_variance(y, noise)
            floor, rule = sigma2, f"noise: σ² = {sigma2:.3g} (δ = {noise:g})"
            rule_drop = self.drop if drop is None else drop
            drop = (1 + np.sqrt(self.m / (n - 1))) ** 2 if rule_drop == "edge" else float(rule_drop)
            cut = max(cut, drop * sigma2)
        else:
            rel = REL_FLOORS.get(self.mean.dtype, REL_FLOOR) if self.rel_floor is None else self.rel_floor
            floor = max(rel * lam[0], cut)
            rule = f"relative: {rel:g}·max λ" if rel * lam[0] >= cut else "numerical rank cut"
        keep = lam >= cut
        if self.rows_per_component is not None:  # Marchenko–Pastur cap (module docstring)
            keep[max(1, int(n // self.rows_per_component)):] = False
        gain = np.where(keep, 1.0 / np.sqrt(np.maximum(lam, floor)), 0.0)
        dtype = self.mean.dtype
        self.mean.copy_(torch.as_tensor(mu, dtype=dtype))
        self.basis.copy_(torch.as_tensor(Vt.T, dtype=dtype))
        self.gain.copy_(torch.as_tensor(gain, dtype=dtype))
        self.fitted.fill_(True)
        self._ready = True  # the flag forward checks, without reading a (device) tensor per call
        self.info = {"floor": float(floor), "floor_rule": rule, "kept": int(keep.sum()),
                     "unit_scale": int((lam >= floor).sum()), "lambda_max": float(lam[0])}
        return self

    def fit_observations(self, y, noise: float | None = None, then=None, **settings) -> Whitening:
        """The hook :func:`pdeinv.nets.fit_preconditioning` calls on every submodule that has it; ``then``:
        the ``nn.Linear`` that takes ``z``, which a folded transform unfolds into (:meth:`unfold`)."""
        if self.folded and then is not None:
            return self.unfold(y, noise, then, **settings)
        return self.fit(y, noise, **settings)

    @torch.no_grad()
    def unfold(self, y, noise, linear, **settings) -> Whitening:
        """Refit a folded transform on ``y`` and move it out of ``linear`` again, keeping the function:
        ``W_f (y − μ) + b = W' D' U'ᵀ (y − μ') + b'`` with ``W' = W_f U' D'⁺`` and ``b' = b + W_f (μ' − μ)``
        (exact on the directions the new fit keeps; :meth:`fit_observations`)."""
        folded, mean = linear.weight.detach().clone(), self.mean.clone()
        self.basis, self.gain = self.mean.new_zeros(self.m, self.k), self.mean.new_ones(self.k)
        self.fit(y, noise, **settings)
        inverse = torch.where(self.gain > 0, 1 / torch.where(self.gain > 0, self.gain, 1), 0)
        linear.weight.copy_((folded @ self.basis.to(folded.dtype)) * inverse.to(folded.dtype))
        linear.bias.add_(folded @ (self.mean - mean).to(folded.dtype))
        return self

    @property
    def folded(self) -> bool:
        """Whether :meth:`fold_into` moved ``D Uᵀ`` into the next layer: the transform only centres."""
        return self.basis.numel() == 0

    @torch.no_grad()
    def fold_into(self, linear) -> bool:
        """``W ← W D Uᵀ`` for the ``nn.Linear`` that takes ``z``, leaving ``y − μ`` here: the same function,
        and the ``(m, k)`` basis no longer saved. Only where ``W`` keeps its shape (``m = k``: a whitening in
        the operator's modes, :mod:`pdeinv.nets.modal`); returns whether it folded. A folded transform is
        refitted only together with that layer (:meth:`unfold`): its ``D Uᵀ`` is in the weights."""
        if not self._ready or self.folded or self.k != self.m or linear.in_features != self.k:
            return False
        linear.weight.copy_(linear.weight @ (self.gain[:, None] * self.basis.T).to(linear.weight.dtype))
        self.basis, self.gain = self.mean.new_zeros(0), self.mean.new_zeros(0)
        return True

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        if y.shape[-1] != self.m:  # before the fitted check: another problem's network says its size
            raise RuntimeError(f"this Whitening takes {self.m} observations per row; got shape "
                               f"{tuple(y.shape)}")
        if self.folded:
            return y - self.mean
        if not self._ready:
            raise RuntimeError(f"this Whitening (m={self.m}) is not fitted: fit it on training observations "
                               "first (whitening.fit(y), or pdeinv.nets.fit_preconditioning(model, y); "
                               "the trainer does it), or load a fitted state dict")
        return ((y - self.mean) @ self.basis) * self.gain

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        basis = state_dict.get(prefix + "basis")
        if basis is not None and basis.numel() == 0:  # a folded transform (fold_into): its shapes
            self.basis, self.gain = self.mean.new_zeros(0), self.mean.new_zeros(0)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._ready = bool(self.fitted)

    def extra_repr(self) -> str:
        k = "" if self.k == self.m else f", components={self.k}"
        floor = "auto" if self.rel_floor is None else f"{self.rel_floor:g}"
        r = "" if self.rows_per_component is None else f", rows_per_component={self.rows_per_component:g}"
        return f"m={self.m}{k}, rel_floor={floor}, drop={self.drop!r}{r}"
