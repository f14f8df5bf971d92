"""What the physics must match: the observations, or a denoised version computed from them alone.

Every physics loss ``½‖P f(y*) − y*‖²`` (GD's, SIP's target ``y + η(y* − y)``, HIG's residual) is
minimized by fitting ``y*`` exactly. With noisy observations ``y* = P x + ε`` that fits the noise:
the iteration semi-converges and only a stopping rule regularizes it (:mod:`pdeinv.training.stopping`).
A **target** ``t(y*)`` fitted on the training observations replaces ``y*`` as what the physics must
match (the network still sees ``y*``), so that the fixed point every rule converges to is a
regularized solution.

:class:`SpectralWiener`: in a spectral basis of the operator, ``P = Out diag(g) Inᵀ`` with
coefficients ``c = y · proj`` (:mod:`pdeinv.physics.backends.compiled`: the modal heat basis, or the SVD in
the
problem's norms), white noise of variance ``σ²`` per component puts ``σ_k² = σ²‖proj_k‖²`` into
coefficient ``k``, independent of the signal. So the signal's second moment per mode is
``E[c_k²] − σ_k²`` — estimated from the training observations alone, never from ``x`` — and the
Wiener filter per mode,

    f_k = 1 − σ_k² / E[c_k²],        t(y) = Σ_k f_k c_k Out_k,

is the best linear filter diagonal in the basis (the "best spectral filter" that any Tikhonov α,
truncated SVD or early-stopped Landweber iteration is a special case of). A network fitted to
``P f(y) = t(y)`` reconstructs ``x_k = f_k c_k / g_k`` on every mode. The part of ``y`` outside the
basis (no ``x`` produces it) is dropped, so that ``t`` lies in ``range(P)`` exactly, whatever the
geometry of the loss: the basis is orthonormal in the problem's norms, and where ``M ≠ I`` the
``M``-complement of the basis has a Euclidean component along ``range(P)``; left in ``t``, that
noise lands in the Euclidean losses of GD and HIG on weak modes, and HIG's near-Gauss–Newton steps
amplify it by ``1/s`` (HIG on heat_2d at 1 %: x-error 0.395 with it left in, the closed form's 0.12 without).

**The protocol** of a target strategy: ``name`` and ``fit(problem, y, noise, model=None,
fields=None)`` returning a fitted target (``t(y)``, with ``info``) or ``None`` (nothing to fit);
``model`` is the network (a fixed decoder changes the basis a filter works in), ``fields`` a callable
returning the training rows' ``x`` or ``None``. A strategy uses what it needs and ignores the rest.

A mode is kept (``f_k > 0``) only where its signal is **significant**: ``mean(c_k²) − σ_k²`` above
``z = 3`` standard errors of the mean of ``c_k²`` *under no signal* (``c_ik ~ N(0, s_i²‖proj_k‖²)``
with each sample's own noise variance ``s_i²`` of the relative noise model: ``√(2 Σ_i s_i⁴)‖proj_k‖²/n``).
(The empirical spread of ``c_k²`` would also hold the signal's own spread, and can drop a leading mode
far above the noise.) A mode is kept only if the x-energy
it implies, ``(mean(c_k²) − σ_k²)/g_k²``, is not above that of all *clearly* detected modes
together. An estimated ``f_k`` of a mode with no signal is sampling error (~√(2/n)) which ``1/g_k``
amplifies without bound on a smoothing operator; the energy guard stops such a fluke even at
``z = 2``, and z = 3 keeps 1–2 more weak modes than z = 4–6. **Clear** is a family-wise level: under
no signal ``n·mean(c_k²)`` is ``Σ_i s_i² χ²₁ ≈ (Σs⁴/Σs²) χ²_ν`` with ``ν = (Σs²)²/Σs⁴`` (Satterthwaite;
``ν = n`` for equal levels), so ``mean(c_k²)/σ_k² ≈ χ²_ν/ν`` and a mode above the ``1 − p/K`` quantile
(``K`` modes, ``p =`` :data:`FAMILY_P`; ≈ 4.4 standard errors for K = 64, n ≈ 1000) is noise with
probability below ``p`` whichever of the ``K`` it is: it is kept whatever its energy (a fixed number
of standard errors would make the verdict on a real mode depend on the row count: tests/test_targets.py).
Only modes between ``z`` and the family-wise level, whose signal *may* be a fluke, are weighed by their
energy. Where ``P`` smooths, the best spectral filter
is about the best Tikhonov filter (y alone cannot say more about modes it cannot see); where it
does not (wave), a filter that knows each mode's signal level beats one α for all modes (wave_2d at
1 %: x-error 0.013 against best-α Tikhonov's 0.024).

**The noise level** is the declared one unless the data show more: modes with ``g_k`` below
:data:`INVISIBLE` of the largest carry no signal a field of the prior's size could put there, so their
coefficients measure the noise; a reading more than ``z`` standard errors above the declared level
replaces it (a level declared too low makes every pure-noise mode look like signal).

**In a decoder's span.** A network with a fixed decoder ``x = D c`` (:func:`pdeinv.nets.reduced`: the
prior's principal components, column ``j`` scaled by the prior's rms amplitude along it) sees the
physics ``P̂ = P D = Q diag(s) Vᵀ``. Where the prior makes ``c`` white (``E[c cᵀ] ≈ I/κ²``: the columns'
scaling) and the noise is white, ``Qᵀy = diag(s) Vᵀc + Qᵀε`` has independent components, and the
Wiener filter per mode of this basis *is* the linear MMSE estimator in ``span D``: ``f_k =
s_k²/(s_k² + σ²κ²) = 1 − σ²/E[(Qᵀy)_k²]``, again estimated from ``y`` alone (the prior chooses the
basis, the data each mode's signal level); at 1 % on the heat scenes it comes within ~1 % of the MMSE
fitted on the training ``x``.

A target is a strategy object::

    fitted = target.fit(problem, y_train, noise[, model])   # None: nothing to fit (use y itself)
    fitted(y) -> numpy (B, m),   fitted.info -> dict  (what it kept, for metrics.json)
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy import stats

from .._checks import positive
from ..inverse.noise import noise_variance
from ..nets.protocol import declared
from ..physics.backends.compiled import spectral_basis
from ..physics.nonlinear import is_linear

#: the chance that any pure-noise mode counts as clearly detected (module docstring)
FAMILY_P = 1e-3


#: modes with ``g_k`` below this fraction of the largest are invisible: a field of the prior's size puts
#: less than 1e-8 of the observations' size into them, below any noise the Wiener filter is fitted for
INVISIBLE = 1e-8


def _invisible_noise(c2, norms, g, y, noise: float, z: float) -> float:
    """The relative noise level to filter with: the invisible modes' (:data:`INVISIBLE`) where it is
    above the declared ``noise`` by more than ``z`` standard errors, else ``noise``. Invisible modes hold
    noise alone, ``E[c_ik²] = s_i² ‖proj_k‖²`` with ``s_i² = δ²/(1 + δ²)·mean(y_i²)``, and a level declared
    too low keeps pure-noise modes that ``1/g_k`` amplifies without bound (heat_1d at 1.4 % noise declared
    as 1 %: SIP's x-error 1e7). No such modes (wave: every mode is seen): ``noise``."""
    g = np.asarray(g)
    dark = g < INVISIBLE * (g.max() if g.size else 0.0)
    if not dark.any() or not noise:
        return noise
    expected = float(norms[dark].sum() * (y**2).mean(1).sum())  # Σ_i Σ_k ‖proj_k‖² mean(y_i²)
    ratio = float(c2[:, dark].sum()) / max(expected, np.finfo(float).tiny)
    if ratio >= 1:
        return noise
    read2 = ratio / (1 - ratio)  # δ²; each c_ik² has relative spread √2, so the mean of K of them √(2/K)
    return float(np.sqrt(read2)) if read2 > noise**2 * (1 + z * np.sqrt(2 / c2[:, dark].size)) else noise


class Filtered:
    """``t(y) = ((y·proj) ⊙ f) Outᵀ``: a fitted spectral filter on observations."""

    def __init__(self, proj: np.ndarray, out: np.ndarray, f: np.ndarray, info: dict):
        self.proj, self.out, self.f, self.info = proj, out, f, info

    def __call__(self, y: np.ndarray) -> np.ndarray:
        y = np.asarray(y, dtype=float)
        return ((y @ self.proj) * self.f) @ self.out.T


@dataclass(frozen=True)
class TrueFields:
    """The training rows' true fields ``x`` as the target (:class:`pdeinv.methods.supervised.Supervised`):
    ``fit(problem, y, noise, fields=x)`` returns a target whose value on the training rows is ``x``.
    Needs ``x``: a scene's own draws or a data file with ``x`` (else ``ValueError``)."""

    name: str = "true_fields"

    def fit(self, problem, y, noise, model=None, fields=None):
        x = None if fields is None else fields()
        if x is None:
            raise ValueError("target TrueFields (supervised training) needs the training rows' x: a data "
                             "file without x has none; give x in the file or use a physics-based rule")
        x = np.asarray(x, dtype=float)
        if len(x) != len(y):
            raise ValueError(f"TrueFields: {len(x)} fields for {len(y)} observations")
        return _Fields(x, np.asarray(y))


class _Fields:
    """A fitted :class:`TrueFields`: the training rows' ``x``, for those rows only."""

    def __init__(self, x: np.ndarray, y: np.ndarray):
        self.x, self.y, self.info = x, y, {"name": "true_fields", "rows": len(x)}

    def __call__(self, y) -> np.ndarray:
        if y is not self.y and not np.array_equal(np.asarray(y), self.y):  # fresh draws: x unknown
            raise ValueError("target TrueFields (supervised training) knows the x of the training rows "
                             "only, and fresh=True (--fresh-draws) trains on new observations whose x no "
                             "loss sees: drop fresh draws, or use a physics-based rule (sip, adam, gd, hig)")
        return self.x


@dataclass(frozen=True)
class SpectralWiener:
    """The y-only Wiener filter per mode of the operator's spectral basis (module docstring)."""

    z: float = 3.0
    name: str = "spectral_wiener"

    def __post_init__(self):
        positive(self.z, "z")

    @staticmethod
    def _basis(problem, model=None):
        decoder = declared(model).decoder
        if decoder is not None and is_linear(problem.operator):  # the physics as the network sees it: P̂ = P D
            from ..inverse.decoder import decoded_svd

            Q, s, _ = decoded_svd(problem.operator, decoder)
            return SimpleNamespace(proj=Q, out=Q, g=s)
        return spectral_basis(problem.operator, None if problem.disc is None else problem.disc.M)

    def applies(self, problem, noise: float | None, model=None) -> bool:
        """Whether :meth:`fit` will fit a filter: a noise level and a spectral basis to filter in."""
        decoded = declared(model).decoder is not None and is_linear(problem.operator)  # P D exists
        return bool(noise) and (decoded or self._basis(problem) is not None)

    def fit(self, problem, y: np.ndarray, noise: float | None, model=None, fields=None) -> Filtered | None:
        """The filter fitted on observations ``y`` ``(n, m)`` with relative noise ``noise``; ``None``
        when there is no noise or the operator has no spectral basis (nothing to filter by). With a
        ``model`` that has a fixed decoder ``D`` (``model.decoder``, :func:`pdeinv.nets.reduced`) the
        basis is the SVD of ``P D`` (module docstring: the MMSE in ``span D``)."""
        if not noise and declared(model).decoder is not None:
            # a nonlinear map has no fixed P D to filter in: the rows' own y is the target
            return self.rounding(problem, model) if is_linear(problem.operator) else None
        if not self.applies(problem, noise, model):
            return None
        return self.fit_basis(self._basis(problem, model), y, noise)

    def rounding(self, problem, model) -> Filtered:
        """Noise-free observations through a decoder: ``t = Q diag(s²/(s² + α)) Qᵀ y`` with the
        rounding-level ``α = REL_ALPHA·s_max²`` of :mod:`pdeinv.inverse.decoder`. SIP's local inverse
        keeps the contract, so its fixed point is the least-squares fit of its target: this target makes
        it the rounding-level Tikhonov solve in ``span D`` (the decoder's missing prior energy and y's
        rounding are not fitted; on heat_cavity_3d it took SIP from 0.0127 to 0.0080)."""
        from ..inverse.decoder import REL_ALPHA

        basis = self._basis(problem, model)
        s = basis.g
        den = s**2 + REL_ALPHA * (s[0] ** 2 if s.size else 0.0)  # 0 where the physics observes nothing
        f = np.divide(s**2, den, out=np.zeros_like(den), where=den > 0)
        return Filtered(basis.proj, basis.out, f, {"name": "tikhonov_rounding", "modes": int(s.size),
                                                   "kept": int(s.size), "rel_alpha": REL_ALPHA})

    def fit_basis(self, modes, y: np.ndarray, noise: float) -> Filtered:
        """The filter in a given basis ``modes`` (``proj``, ``out``, ``g``: ``P = out diag(g) projᵀ``-like,
        ``c = y·proj``), fitted on observations ``y`` with relative noise ``noise``."""
        y = np.asarray(y, dtype=float)
        n = y.shape[0]
        c2 = (y @ modes.proj) ** 2
        power = c2.mean(0)
        norms = (modes.proj**2).sum(0)
        declared_noise, noise = noise, _invisible_noise(c2, norms, modes.g, y, noise, self.z)
        sigma2 = noise_variance(y, noise) * norms
        # the standard error of mean(c_k²) under "no signal": c_ik ~ N(0, s_i² ‖proj_k‖²) with the
        # sample's own noise variance s_i² (relative noise), Var(c²) = 2 s_i⁴ ‖proj_k‖⁴
        s2 = noise**2 / (1 + noise**2) * (y**2).mean(1)
        se = np.sqrt(2 * (s2**2).sum()) * norms / n
        signal = power - sigma2
        significant = signal > self.z * se
        # the energy guard: a mode that may be a fluke may not claim more x-energy (signal/g²) than all
        # clearly detected modes together; a sampling fluke on a mode with tiny g would. Clear: above
        # the family-wise level of the null χ²_ν/ν, whatever the row count (module docstring)
        energy = signal / np.maximum(modes.g**2, np.finfo(float).tiny)
        nu = s2.sum() ** 2 / max(float((s2**2).sum()), np.finfo(float).tiny)
        clear = power > sigma2 * stats.chi2.isf(FAMILY_P / power.size, nu) / nu
        if clear.any():
            significant &= energy <= energy[clear].sum()
        f = np.where(significant, 1.0 - sigma2 / np.maximum(power, np.finfo(float).tiny), 0.0)
        info = {"name": self.name, "modes": int(f.size), "kept": int(significant.sum()), "z": self.z,
                "noise": float(noise)}
        if noise > declared_noise:  # the data showed more than was declared
            info["declared_noise"] = float(declared_noise)
        return Filtered(modes.proj, modes.out, f, info)
