"""The linear-Gaussian posterior, exact and low-rank: the reference every learned posterior is judged by.

Prior ``x ~ N(m, C)`` with ``C = L Lᵀ`` (``L`` is ``(N, r)``), observations ``y = P x + e``,
``e ~ N(0, σ² I)`` on the observation coefficients. The posterior is Gaussian,

    C_post = C − C Pᵀ (P C Pᵀ + σ² I)⁻¹ P C = L (I + H̃)⁻¹ Lᵀ,
    μ(y)   = m + L (I + H̃)⁻¹ (P L)ᵀ (y − P m) / σ²,

with the **prior-preconditioned data-misfit Hessian** ``H̃ = (P L)ᵀ (P L) / σ²`` (``r × r``; hIPPYlib's
``GaussianLRPosterior``, Bui-Thanh et al. 2013). With its eigenpairs ``H̃ = V Λ Vᵀ`` (those above
``tol``; a smoothing operator has few) and ``D = Λ / (1 + Λ)``:

    (I + H̃)⁻¹ = I − V D Vᵀ,            var_i = Σ_j L_ij² − Σ_k (L V √D)_ik²,
    (I + H̃)^{-1/2} = I − V (I − (I + Λ)^{-1/2}) Vᵀ   (exact samples ``μ + L (I + H̃)^{-1/2} ζ``).

The eigenpairs come from the singular triplets ``P L / σ = U diag(√λ) Vᵀ``, by a randomized SVD
(Halko, Martinsson & Tropp 2011) whose products are one batched forward and one batched adjoint of the
physics (:func:`singular_triplets`); the rank doubles until the smallest eigenvalue found is below
``tol`` (dropped directions reduce the variance by less than ``tol`` of the prior's), or the SVD is
exact. The mean is computed as ``m + L V diag(√λ/(1+λ)) Uᵀ (y − P m)/σ``, without the cancellation of
the formula above at small ``σ``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._checks import batch


@dataclass(frozen=True)
class GaussianPrior:
    """``N(mean, factor factorᵀ)``: ``mean`` ``(N,)``, ``factor`` ``(N, r)``."""

    mean: np.ndarray
    factor: np.ndarray

    @classmethod
    def from_draws(cls, x: np.ndarray, rtol: float = 1e-10) -> GaussianPrior:
        """The empirical mean and covariance of draws ``x`` ``(n, N)``: ``C = X_cᵀ X_c / (n − 1)``, as the
        thin-SVD factor ``V S / √(n−1)`` of the centred draws, components above ``rtol`` of the largest
        kept (the rest are rounding)."""
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or len(x) < 2:
            raise ValueError(f"x has shape {x.shape}; expected (n, N) draws with n ≥ 2")
        mean = x.mean(axis=0)
        _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
        keep = s > rtol * s[0] if s[0] > 0 else np.zeros_like(s, dtype=bool)
        return cls(mean, vt[keep].T * (s[keep] / np.sqrt(len(x) - 1)))

    @property
    def variance(self) -> np.ndarray:
        return np.einsum("ij,ij->i", self.factor, self.factor)


def noise_std(operator, prior: GaussianPrior, level: float) -> float:
    """The absolute noise std ``σ = δ·rms(P x)`` of :func:`pdeinv.problem.sampling.add_noise` averaged over
    the prior: ``σ² = δ² (‖P L‖_F² + ‖P m‖²) / m_obs`` (the relative noise of each row, as one Gaussian)."""
    PL = operator.forward(prior.factor.T)
    Pm = operator.forward(prior.mean[None])[0]
    return float(level * np.sqrt(((PL**2).sum() + (Pm**2).sum()) / operator.n_out))


def singular_triplets(operator, factor: np.ndarray, sigma: float, tol: float, rank: int = 32,
                      oversample: int = 10, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(λ, U, V)`` with ``P L / σ ≈ U diag(√λ) Vᵀ``, the pairs with ``λ ≥ tol``, descending (``λ`` are the
    eigenvalues of ``H̃``, ``V`` its eigenvectors). Randomized (Halko et al. 2011, Alg. 5.1: a range
    sketch by one batched forward, its projection by one batched adjoint, an SVD of the small matrix) at
    ranks ``rank, 2·rank, …`` until the smallest ``λ`` found is below ``tol``, or exact once the sketch
    is as wide as ``P L`` (its ``r`` columns through the forward map and a thin SVD). Never ``H̃`` itself:
    its small eigenvalues would drown in the rounding of its large ones (λ spans 20 decades for
    noise-free heat)."""
    r, m = factor.shape[1], operator.n_out

    def forward(W):  # (P L / σ) W, (r, l) -> (m, l)
        return operator.forward((factor @ W).T).T / sigma

    rng = np.random.default_rng(seed)
    while True:
        width = rank + oversample
        if width >= min(r, m):
            U, s, Vt = np.linalg.svd(forward(np.eye(r)), full_matrices=False)
            break
        Q, _ = np.linalg.qr(forward(rng.standard_normal((r, width))))
        B = (factor.T @ operator.adjoint(Q.T).T / sigma).T  # Qᵀ (P L / σ), (width, r)
        Ub, s, Vt = np.linalg.svd(B, full_matrices=False)
        U, s, Vt = Q @ Ub[:, :rank], s[:rank], Vt[:rank]  # the oversampled tail is the inaccurate part
        if s[-1] ** 2 < tol:
            break
        rank *= 2
    keep = s**2 >= tol
    return s[keep] ** 2, U[:, keep], Vt[keep].T


class LinearGaussian:
    """The exact posterior of a linear operator under a :class:`GaussianPrior` and noise std ``sigma``
    (module docstring): :meth:`mean`, :attr:`std`, :meth:`sample`, :meth:`interval`, :meth:`covariance`.

    ``sigma`` must be positive: noise-free data are still rounded, and ``σ → 0`` leaves the directions the
    data cannot see at their prior variance and pins the others (pass the rounding level)."""

    def __init__(self, operator, prior: GaussianPrior, sigma: float, tol: float = 1e-10, seed: int = 0):
        if not (np.isfinite(sigma) and sigma > 0):
            raise ValueError(f"sigma={sigma!r} is not allowed; expected a positive noise std")
        if prior.factor.shape[0] != operator.n_in:
            raise ValueError(f"the prior has {prior.factor.shape[0]} unknowns; the operator {operator.n_in}")
        self.operator, self.prior, self.sigma = operator, prior, float(sigma)
        self.eigenvalues, self._U, V = singular_triplets(operator, prior.factor, self.sigma, tol, seed=seed)
        self._LV = prior.factor @ V  # (N, k)
        self._V = V
        d = self.eigenvalues / (1.0 + self.eigenvalues)
        self.std = np.sqrt(np.maximum(prior.variance - np.einsum("ik,k,ik->i", self._LV, d, self._LV), 0))

    @property
    def rank(self) -> int:
        return len(self.eigenvalues)

    def mean(self, y) -> np.ndarray:
        """``μ(y)`` row-wise, ``(B, m) → (B, N)``: ``m + L V diag(√λ/(1+λ)) Uᵀ (y − P m)/σ`` with
        ``P L V = σ U diag(√λ)`` (the same as the module docstring's formula, whose ``g`` is huge at small
        ``σ`` and cancels)."""
        Y, single = batch(y, self.operator.n_out, "y")
        lam = self.eigenvalues
        r = (Y - self.operator.forward(self.prior.mean[None])) / self.sigma
        out = self.prior.mean + ((r @ self._U) * (np.sqrt(lam) / (1 + lam))) @ self._LV.T
        return out[0] if single else out

    def sample(self, y, k: int, seed: int = 0) -> np.ndarray:
        """``k`` exact posterior draws per observation: ``(B, k, N)`` (``(k, N)`` for one ``y``)."""
        mu = self.mean(y)
        single = mu.ndim == 1
        mu = np.atleast_2d(mu)
        r = self.prior.factor.shape[1]
        z = np.random.default_rng(seed).standard_normal((len(mu), k, r))
        shrink = 1.0 - 1.0 / np.sqrt(1.0 + self.eigenvalues)
        z = z - ((z @ self._V) * shrink) @ self._V.T
        out = mu[:, None, :] + z @ self.prior.factor.T
        return out[0] if single else out

    def interval(self, y, level: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
        """The central per-node credible interval at ``level``: ``μ ∓ z σ_i``."""
        from scipy.special import ndtri

        mu, z = self.mean(y), ndtri(0.5 + level / 2)
        return mu - z * self.std, mu + z * self.std

    def covariance(self) -> np.ndarray:
        """The dense ``(N, N)`` posterior covariance (small problems and tests)."""
        d = self.eigenvalues / (1.0 + self.eigenvalues)
        L = self.prior.factor
        return L @ L.T - (self._LV * d) @ self._LV.T
