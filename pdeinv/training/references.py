"""Linear reference reconstructions: the limits the trained networks are measured against.

Both are fitted on a training set ``(X, Y)`` and evaluated on a test set, with the
relative L²(Ω) error of :meth:`pdeinv.Problem.relative_error`.

**Linear MMSE** (the optimal linear estimator for the training distribution):
with the training mean ``μ`` and covariance ``C_x = L Lᵀ``, ``L = X̄ᵀ/√(n−1)``
(``X̄`` the centred samples), and ``G = P L`` (the noise-free images of the centred
samples, no explicit ``P`` needed),

    x̂ = μ + W (y − Pμ),    W = C_x Pᵀ (P C_x Pᵀ + σ² I)⁻¹ = L V diag(s/(s²+σ²)) Uᵀ,

with the thin SVD ``G = U diag(s) Vᵀ`` (the push-through identity; it avoids forming
``P C_x Pᵀ``, which would square the condition number and lose the weakly observed
modes to rounding). ``σ² = noise² · mean_i rms(P x_i)²`` is the variance of the
problem's relative noise (:func:`pdeinv.problem.sampling.add_noise`). With ``noise = 0``
the inverse is singular; we then use the *tiny σ* ``σ = 1e-8 · s_max`` (not a
hard pseudo-inverse): a smooth cut where rounding in ``y`` (~1e-16) would start
to dominate.
The MMSE estimator minimizes ``E‖x̂ − x‖²_G`` for every SPD weight ``G``, so it is
the same in the Euclidean and the L²(Ω) norm.

**Best-α Tikhonov**: ``x̂_α = argmin ½‖P x − y‖²_D + ½ α ‖x‖²_M`` with ``D = M`` when
``y`` is a field on the mesh (as the operator declares,
:mod:`pdeinv.physics.capabilities`; else the identity), for ``α = a · s_max²`` on a grid
of ``a``; the α with the lowest mean test x-error wins (an oracle choice: a
lower bound for any α rule). With ``M = LLᵀ`` and ``z = Lᵀx``, ``Q = L_Dᵀ P L⁻ᵀ``
has the SVD ``Q = U S Vᵀ`` and ``x̂_α = L⁻ᵀ V diag(s/(s²+α)) Uᵀ L_Dᵀ y`` for all α
at once. ``P`` is formed densely (``N`` forward columns): meant for N ≲ 5000. Beyond,
:func:`tikhonov_best_krylov` solves the same problem matrix-free, every α of the grid from one
generalized Golub–Kahan space per test row (:mod:`pdeinv.inverse.bidiag`).

**Best spectral filter** (an oracle bound for every filter method): in the same
basis every *spectral filter* reconstructs ``x̂ = L⁻ᵀ V diag(f/s) Uᵀ L_Dᵀ y`` —
Tikhonov ``f = s²/(s²+α)``, truncated SVD ``f ∈ {0, 1}``, ``k`` Landweber or
early-stopped gradient steps on a linear model ``f = 1 − (1 − ω s²)^k``. With
``c = Vᵀ Lᵀ x`` (so ``‖x̂ − x‖²_M`` splits into one term per mode plus the part of
``x`` outside ``span V``) and ``d = Uᵀ L_Dᵀ y / s``, the filter minimizing the
training error is ``f_k = Σ c_k d_k / Σ d_k²`` per mode, fitted on the *training*
pairs ``(X, Y)`` and evaluated on the test set. No filter does better on the
training distribution, which bounds what a physics-loss method whose implicit
regularization acts mode by mode can reach.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from ..physics.backends.compiled import Dense, matrix
from ..physics.capabilities import modal_basis, observes_field
from ..physics.nonlinear import require_linear

#: σ / s_max used when the problem is noise-free (see the module docstring)
TINY_SIGMA = 1e-8
#: α / s_max² tried by :func:`tikhonov_best`
ALPHA_GRID = tuple(10.0 ** -k for k in range(0, 15))


def _noise_variance(problem, Y_clean: np.ndarray) -> float:
    return float(problem.noise) ** 2 * float(np.mean(Y_clean**2))


def mmse(problem, X: np.ndarray, sigma2: float | None = None):
    """``(estimator, info)``: ``estimator(Y) -> X̂`` the linear MMSE fitted on training fields ``X``."""
    X = np.asarray(X, dtype=float)
    n = X.shape[0]
    if n < 2:
        raise ValueError(f"the MMSE needs at least 2 training samples; got {n}")
    mu = X.mean(0)
    # W is the same for (a X, a Y, a² σ²): the factors are made from X / a, so that fields in any units
    # (1e-200 or 1e200) neither underflow nor overflow in s²
    a = float(np.max(np.abs(X - mu))) or 1.0
    L = (X - mu).T / (a * np.sqrt(n - 1))  # (N, n), the prior's square root over a
    G = problem.operator.forward(L.T).T  # P L, (m, n)
    U, s, Vt = np.linalg.svd(G, full_matrices=False)
    if sigma2 is None:
        sigma2 = _noise_variance(problem, problem.operator.forward(X)) if problem.noise else 0.0
    floor = (TINY_SIGMA * s[0]) ** 2
    used = float(max(float(sigma2) / a / a, floor))
    Wt = (U * (s / (s**2 + used))) @ (Vt @ L.T)  # Wᵀ = U diag(s/(s²+σ²)) Vᵀ Lᵀ, the same for every a
    Pmu = problem.operator.forward(mu[None])[0]

    def estimate(Y):
        return mu + (np.asarray(Y) - Pmu) @ Wt

    rule = "noise" if sigma2 / a / a >= floor else "tiny σ = 1e-8·s_max"
    info = {"sigma2": used * a * a, "sigma2_rule": rule, "n_train": n}
    return estimate, info


def dense_operator(problem, chunk: int = 256) -> np.ndarray:
    """``P`` as a dense ``(n_out, n_in)`` array: the compiled one if the operator has it
    (:mod:`pdeinv.physics.backends.compiled`), from its spectral basis ``out diag(g) Inᵀ`` (modal or SVD,
    exact to the basis' tolerance), else from forward runs on identity columns."""
    op = problem.operator
    require_linear(op, "a dense matrix of P (the linear references: Tikhonov, MMSE, Wiener)")
    backend, basis = op.backend, modal_basis(op)
    if isinstance(backend, Dense):
        return backend.P
    if basis is not None:
        return (basis.out * basis.g) @ basis.In.T
    return matrix(op.forward, op.n_in, op.n_out, chunk)


def _spectral_basis(problem, P: np.ndarray | None = None):
    """``(LD, L, U, s, V, back)`` with ``L_Dᵀ P L⁻ᵀ = U diag(s) Vᵀ`` and ``back = L⁻ᵀ V``."""
    P = dense_operator(problem) if P is None else P
    M = problem.disc.M.toarray()
    L = np.linalg.cholesky(M)
    LD = L if observes_field(problem.operator) else np.eye(P.shape[0])
    Q = LD.T @ sla.solve_triangular(L, P.T, lower=True).T  # L_Dᵀ P L⁻ᵀ
    U, s, Vt = np.linalg.svd(Q, full_matrices=False)
    back = sla.solve_triangular(L.T, Vt.T, lower=False)  # L⁻ᵀ V
    return LD, L, U, s, Vt.T, back


def tikhonov_path(problem, P: np.ndarray | None = None):
    """``(solve, s_max)``: ``solve(Y, alpha) -> X̂`` for any α, from one SVD."""
    LD, _, U, s, _, back = _spectral_basis(problem, P)

    def solve(Y, alpha):
        coef = (np.asarray(Y) @ LD) @ U  # (L_Dᵀ y)ᵀ U
        return (coef * (s / (s**2 + alpha))) @ back.T

    return solve, float(s[0])


def best_filter(problem, X_train, Y_train, X_test, Y_test, P=None) -> dict:
    """The best spectral filter ``f`` fitted on the training pairs (module docstring), on the test set."""
    LD, L, U, s, V, back = _spectral_basis(problem, P)
    keep = s > s[0] * np.finfo(float).eps  # numerically zero modes get f = 0
    U, s, V, back = U[:, keep], s[keep], V[:, keep], back[:, keep]
    c = (np.asarray(X_train) @ L) @ V  # Vᵀ Lᵀ x, per row
    d = ((np.asarray(Y_train) @ LD) @ U) / s
    f = np.sum(c * d, axis=0) / np.maximum(np.sum(d * d, axis=0), np.finfo(float).tiny)
    X_hat = (((np.asarray(Y_test) @ LD) @ U) * (f / s)) @ back.T
    return {"x_err": float(np.mean(problem.relative_error(X_hat, X_test))), "filter": f}


def tikhonov_best(problem, Y_test, X_test, grid=ALPHA_GRID, P=None) -> dict:
    """Sweep ``α = a · s_max²`` over ``grid``; the lowest mean relative test x-error wins."""
    solve, smax = tikhonov_path(problem, P)
    errs = []
    for a in grid:
        err = float(np.mean(problem.relative_error(solve(Y_test, a * smax**2), X_test)))
        errs.append(err if np.isfinite(err) else np.inf)
    best = int(np.argmin(errs))
    return {"x_err": errs[best], "alpha_rel": grid[best], "alpha": grid[best] * smax**2,
            "sweep": dict(zip([f"{a:.0e}" for a in grid], errs, strict=True))}


def tikhonov_best_krylov(problem, Y_test, X_test, grid=ALPHA_GRID, iterations: int = 200,
                         converged: float = 1e-2) -> dict:
    """:func:`tikhonov_best` without a dense ``P``: ``iterations`` generalized Golub–Kahan steps per test row
    (one batched forward and adjoint each, :func:`pdeinv.inverse.bidiag.bidiagonalize`), then every α of
    ``grid`` (relative to the resolved ``s_max²``) in that space. An α counts only where its solutions have
    converged: their relative change when the last half of the iterations is dropped is below ``converged``
    (a small α needs a larger space, and a truncated space regularizes on its own: what it gives is not
    Tikhonov's). ``unconverged_x_err``: the best of the others, for comparison."""
    from ..inverse.bidiag import bidiagonalize

    require_linear(problem.operator, "the Krylov Tikhonov reference")
    space = bidiagonalize(problem.operator, Y_test, problem.disc.M if problem.disc else None,
                          iterations=iterations)
    half, smax = space.truncated(space.info["iterations"] // 2), space.s_max
    errs, changes = [], []
    for a in grid:
        X, Xh = space.solve(a * smax**2), half.solve(a * smax**2)
        errs.append(float(np.mean(problem.relative_error(X, X_test))))
        changes.append(float(np.linalg.norm(X - Xh) / max(np.linalg.norm(X), 1e-300)))
    ok = [i for i, c in enumerate(changes) if c < converged]
    if not ok:
        raise ValueError(f"tikhonov_best_krylov: no α of the grid converged in {space.info['iterations']} "
                         f"iterations (smallest change {min(changes):.2g}); give more iterations")
    best = min(ok, key=lambda i: errs[i])
    others = [errs[i] for i in range(len(grid)) if i not in ok]
    return {"x_err": errs[best], "alpha_rel": grid[best], "alpha": grid[best] * smax**2,
            "converged": changes[best], "iterations": space.info["iterations"],
            "unconverged_x_err": min(others) if others else None,
            "sweep": {f"{a:.0e}": (e, c) for a, e, c in zip(grid, errs, changes, strict=True)}}


def prior_wiener(problem, Y_train: np.ndarray, noise: float):
    """``(estimator, info)``: the y-only estimator the default network converges to where the operator
    is not reversible (:func:`pdeinv.nets.default_model`): in the prior decoder's span ``D``
    (:func:`pdeinv.nets.decoder_basis`) with ``P D = Q diag(s) Vᵀ``,

        x̂ = D V diag(f / s) Qᵀ y,

    ``f`` the Wiener factors fitted on the observations ``Y_train`` alone
    (:meth:`pdeinv.methods.targets.SpectralWiener.fit_basis`; with ``noise = 0`` the rounding-level Tikhonov
    factors of :class:`~pdeinv.inverse.decoder.DecoderTikhonov`). Where the problem's prior describes
    the data it reaches the linear MMSE (module docstring of :mod:`pdeinv.methods.targets`) without ``x``."""
    from types import SimpleNamespace

    from ..inverse.decoder import REL_ALPHA, decoded_svd
    from ..methods.targets import SpectralWiener
    from ..nets.reduced import decoder_basis

    D, info = decoder_basis(problem)
    Q, s, V = decoded_svd(problem.operator, D.T)
    if noise:
        fitted = SpectralWiener().fit_basis(SimpleNamespace(proj=Q, out=Q, g=s), Y_train, noise)
        f, kept = fitted.f, fitted.info["kept"]
    else:
        f, kept = s**2 / (s**2 + REL_ALPHA * s[0] ** 2), len(s)
    back = (V * (f / s)).T @ D.T  # diag(f/s) Vᵀ Dᵀ, (r, N)

    def estimate(Y):
        return (np.asarray(Y, dtype=float) @ Q) @ back

    return estimate, {"components": D.shape[1], "modes": len(s), "kept": int(kept)}


def references(problem, X_train, X_test, Y_test, Y_train=None) -> dict:
    """``mmse_x_err``, ``tikhonov_best_x_err`` and what they used, on the given test set;
    with the training data ``Y_train`` also ``filter_best_x_err`` (:func:`best_filter`)."""
    est, info = mmse(problem, X_train)
    mm = float(np.mean(problem.relative_error(est(Y_test), X_test)))
    P = dense_operator(problem)
    tk = tikhonov_best(problem, Y_test, X_test, P=P)
    out = {"mmse_x_err": mm, "mmse": info, "tikhonov_best_x_err": tk["x_err"],
           "tikhonov": {k: v for k, v in tk.items() if k != "x_err"}}
    if Y_train is not None:
        out["filter_best_x_err"] = best_filter(problem, X_train, Y_train, X_test, Y_test, P=P)["x_err"]
    return out


#: relative α of the Levenberg–Marquardt iteration (:func:`levenberg_marquardt`) tried for the oracle
LM_ALPHAS = (1e-1, 1e-2, 1e-3, 1e-4)


def levenberg_marquardt(problem, Y: np.ndarray, rel_alpha: float, iterations: int = 10,
                        noise: float = 0.0, tau: float = 1.1) -> tuple[np.ndarray, dict]:
    """Per-sample regularized Gauss–Newton from ``x = 0`` for a map of any kind (the classical
    reference where no matrix exists): ``x ← x + Δx`` with ``Δx`` the regularized Gauss–Newton step
    at ``x`` (:class:`~pdeinv.inverse.gauss_newton.GaussNewtonInverse`, ``α = rel_alpha·λ_max``), at
    most ``iterations`` times; with ``noise`` a row stops once its residual ``‖P(x) − y‖/‖y‖`` is below
    ``tau·noise`` (Morozov's discrepancy principle for the iteration, Hanke 1997). ``(X, info)`` with
    the seconds per sample."""
    import time

    from ..inverse.gauss_newton import GaussNewtonInverse

    op, M = problem.operator, problem.disc.M
    inv = GaussNewtonInverse(op, M, rel_alpha=rel_alpha)
    X, live, t0 = np.zeros((len(Y), problem.N)), np.ones(len(Y), dtype=bool), time.perf_counter()
    norms = np.linalg.norm(Y, axis=1)
    for _ in range(iterations):
        if noise > 0:
            live &= np.linalg.norm(op.forward(X) - Y, axis=1) > tau * noise * norms
        if not live.any():
            break
        X[live] = inv(Y[live], X[live])
    return X, {"rel_alpha": rel_alpha, "iterations": iterations,
               "s_per_sample": (time.perf_counter() - t0) / max(len(Y), 1)}


#: prior draws of the linear-Gaussian reference's covariance by default: at most this many numbers
#: (32 MB), 256 to 4096 draws (the covariance's sampling error falls as 1/√draws; its thin SVD costs
#: draws·N² flops)
GAUSSIAN_NUMBERS, GAUSSIAN_DRAWS = 4_000_000, (256, 4096)
#: noise-free data are still rounded: the reference's relative noise floor there (the NOISE_FLOOR a
#: noise estimate reads as clean data, pdeinv.training.data)
GAUSSIAN_FLOOR = 1e-10


def gaussian_posterior(problem, noise: float, seed: int = 0, draws: int | None = None):
    """``(posterior, info)``: the exact linear-Gaussian posterior (:class:`pdeinv.posterior.LinearGaussian`)
    with the problem's prior taken as Gaussian, its mean and covariance from prior draws
    (:meth:`~pdeinv.posterior.GaussianPrior.from_draws`; ``draws``, or the default count above), and the
    relative noise ``noise`` (at least
    :data:`GAUSSIAN_FLOOR`) as one Gaussian (:func:`pdeinv.posterior.gaussian.noise_std`). Where the prior
    is Gaussian it is the best any estimate can do, error bars included."""
    from ..posterior import GaussianPrior, LinearGaussian
    from ..posterior.gaussian import noise_std

    lo, hi = GAUSSIAN_DRAWS
    n = draws or int(min(hi, max(lo, GAUSSIAN_NUMBERS // problem.N)))
    prior = GaussianPrior.from_draws(problem.sample(n, seed=seed)[0])
    level = max(noise, GAUSSIAN_FLOOR)
    post = LinearGaussian(problem.operator, prior, noise_std(problem.operator, prior, level), seed=seed)
    return post, {"draws": n, "rank": post.rank, "noise_level": level}
