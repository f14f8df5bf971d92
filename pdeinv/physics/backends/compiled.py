"""Compiled backends for a fixed linear operator: its action computed once, applied by BLAS.

Every operator here is linear and fixed for a whole training run, so a run that applies it
thousands of times can pay once for a form that makes each application cheap:

* :class:`Dense`: ``P`` as an ``(m, N)`` array, built from batched runs of the time stepping
  on identity columns (``chunk`` at a time). Forward ``X Pᵀ``, adjoint ``R P``: exact
  transposes of each other; ``P`` agrees with the stepping it was built from to rounding.
* :class:`SVD`: the truncated SVD in the problem's norms. With ``M = L Lᵀ`` (input mass) and
  ``M_out = L_o L_oᵀ`` (the mass of a field observation; the identity for records),

      L_oᵀ P L⁻ᵀ = U S Vᵀ,      P ≈ Out diag(s) Inᵀ,   Out = L_o⁻ᵀ U,   In = L V,

  keeping ``s ≥ rtol · s_max``: the dropped part has operator norm below ``rtol · s_max``
  from ``‖·‖_M`` to ``‖·‖_{M_out}``. It is also a *spectral basis* (``g = s``, ``proj = L_o U``,
  ``out = Out``, ``synth = L⁻ᵀ V``): the Tikhonov inverse becomes a filter per singular value
  and Morozov's α a closed form per sample (:class:`pdeinv.inverse.SpectralTikhonov`), as
  for the modal backend (:mod:`.modal`).

:func:`plan` chooses among stepping, these and the modal form of a symmetric θ-scheme
(:mod:`.modal`) by a cost model of what a training run will
do (forward, adjoint and the local inverse per step over the expected steps, plus the
build) under a memory budget (:data:`BUDGET_GB`, env ``PDEINV_DENSE_BUDGET_GB``); an explicit
choice over budget is refused with the size it needs, ``auto`` falls back to stepping.
"""

from __future__ import annotations

import os
from contextlib import contextmanager

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

from ..capabilities import Spectral, modal_basis, output_mass
from .lowrank import RankTooHigh, svd_from_products

#: default memory budget of a dense or SVD backend, in GB (env PDEINV_DENSE_BUDGET_GB overrides)
BUDGET_GB = 1.0
#: relative singular-value cut of :class:`SVD`
SVD_RTOL = 1e-12
#: what :func:`plan` assumes of a training run: steps, batch columns, CG iterations of a generic inverse
EXPECT = {"steps": 1000, "batch": 32, "cg_iterations": 100}
#: BLAS products run this many times more flops per second than sparse solves (measured 4-10x)
BLAS_ADVANTAGE = 4.0


@contextmanager
def expecting(steps: int | None = None, batch: int | None = None):
    """Within the block, :func:`plan` assumes a training run of ``steps`` steps of ``batch``
    columns (``None``: keep :data:`EXPECT`'s). ``pdeinv train`` passes its ``--steps``:
    ``with expecting(steps=50): problem = load_problem("wave_2d")``."""
    given = {k: v for k, v in (("steps", steps), ("batch", batch)) if v is not None}
    for name, v in given.items():
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name}={v!r} is not allowed; expected an integer >= 1")
    before = dict(EXPECT)
    EXPECT.update(given)
    try:
        yield
    finally:
        EXPECT.clear()
        EXPECT.update(before)


def budget_gb() -> float:
    raw = os.environ.get("PDEINV_DENSE_BUDGET_GB")
    if raw is None:
        return BUDGET_GB
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not value > 0:
        raise ValueError(f"PDEINV_DENSE_BUDGET_GB={raw!r} is not allowed; expected a number of GB > 0")
    return value


def matrix(run, n_in: int, n_out: int, chunk: int = 256) -> np.ndarray:
    """``P`` as an ``(n_out, n_in)`` array from ``run(E)`` on identity rows, ``chunk`` at a time."""
    P = np.empty((n_out, n_in))
    for i in range(0, n_in, chunk):
        E = np.zeros((min(chunk, n_in - i), n_in))
        E[np.arange(len(E)), i + np.arange(len(E))] = 1.0
        P[:, i:i + len(E)] = run(E).T
    return P


class Dense:
    """``P`` stored densely (module docstring)."""

    name = "dense"

    def __init__(self, P: np.ndarray):
        self.P, self.PT = np.ascontiguousarray(P), np.ascontiguousarray(P.T)

    @staticmethod
    def nbytes(n_in: int, n_out: int) -> int:
        return 2 * 8 * n_in * n_out

    def forward(self, X):
        return X @ self.PT

    def flops(self) -> float:
        """One column's :meth:`forward`: ``2mN``."""
        return 2.0 * self.P.size

    def adjoint(self, R):
        return R @ self.P


class _Identity:
    """The Cholesky factor of no mass (the Euclidean norm), never formed: records of 10⁵ observations asked
    ``np.eye`` for 75 GiB."""

    T = property(lambda self: self)

    def __matmul__(self, X):
        return X

    def solve(self, X):
        return X


class _Factor:
    """``L`` with ``M = L Lᵀ``: products ``L @ X``, ``L.T @ X`` and triangular solves with either."""

    def __init__(self, L, transposed: bool = False):
        self.L, self.transposed = L, transposed

    @property
    def T(self):
        return _Factor(self.L, not self.transposed)

    def __matmul__(self, X):
        return (self.L.T if self.transposed else self.L) @ X

    def solve(self, X):
        return la.solve_triangular(self.L, X, lower=True, trans="T" if self.transposed else "N")


def _chol(M):
    """``M``'s Cholesky factor (:class:`_Factor`), or the identity for ``None``."""
    if M is None:
        return _Identity()
    return _Factor(la.cholesky(M.toarray() if sp.issparse(M) else M, lower=True))


class SVD(Spectral):
    """Truncated SVD of ``P`` in the norms of ``M`` (input) and ``M_out`` (output; module docstring)."""

    name = "svd"

    ARRAYS = ("g", "In", "out", "proj", "synth")

    @classmethod
    def restore(cls, arrays: dict, M_out=None) -> SVD:
        """The SVD from its :attr:`ARRAYS` (e.g. a cache entry)."""
        self = cls.__new__(cls)
        for name in cls.ARRAYS:
            setattr(self, name, np.ascontiguousarray(arrays[name]))
        self.mass_out = M_out
        return self

    def __init__(self, P: np.ndarray, M=None, M_out=None, rtol: float = SVD_RTOL):
        if not 0 < rtol < 1:
            raise ValueError(f"rtol={rtol!r} is not allowed; expected 0 < rtol < 1")
        m, n = P.shape
        L, Lo = _chol(M), _chol(M_out)
        Q = Lo.T @ L.solve(P.T).T  # L_oᵀ P L⁻ᵀ
        U, s, Vt = np.linalg.svd(Q, full_matrices=False)
        keep = s >= rtol * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
        U, V = U[:, keep], Vt[keep].T
        self.g, self.mass_out = s[keep], M_out
        self.In = np.ascontiguousarray(L @ V)
        self.out = np.ascontiguousarray(Lo.T.solve(U))
        self.proj = np.ascontiguousarray(Lo @ U)
        self.synth = np.ascontiguousarray(L.T.solve(V))

    @staticmethod
    def nbytes(n_in: int, n_out: int) -> int:
        return 8 * (4 * n_in * n_out + 2 * (n_in + n_out) * min(n_in, n_out))  # build peak



class LazySVD(Spectral):
    """The :class:`SVD` of a dense ``P`` in the norms ``M``, ``M_out``, computed on first use: a spectral
    basis (``g``, ``proj``, ``out``, ``synth``, ``mass_out``) for a dense backend, so that only a run
    that asks for it (SIP's spectral inverse) pays the ``O(m N min(m, N))`` factorization."""

    ARRAYS = ("g", "In", "out", "proj", "synth")

    def __init__(self, P: np.ndarray, M=None, M_out=None):
        self.P, self.M, self.mass_out, self._svd = P, M, M_out, None

    def _arrays(self) -> SVD:
        if self._svd is None:
            self._svd = SVD(self.P, self.M, self.mass_out)
        return self._svd

    g = property(lambda self: self._arrays().g)
    In = property(lambda self: self._arrays().In)
    out = property(lambda self: self._arrays().out)
    proj = property(lambda self: self._arrays().proj)
    synth = property(lambda self: self._arrays().synth)


def spectral_basis(op, M=None):
    """A spectral basis of ``op`` (``g``, ``proj``, ``out``, ``synth``, ``mass_out``): its own
    (``op.modes``: modal heat, compiled SVD), else the SVD of a compiled dense ``P`` in the norms of
    ``M`` (:class:`LazySVD`, computed once per backend and mass on first use), else ``None``."""
    modes = modal_basis(op)
    if modes is not None:
        return modes
    backend = op.backend
    if not isinstance(backend, Dense):
        return None
    P = backend.P
    cache = backend.__dict__.setdefault("_spectral", {})  # the LazySVD keeps M alive: its id stays unique
    M_out = output_mass(op, M)
    key = (id(M), M_out is not None)
    if key not in cache:
        cache[key] = LazySVD(P, M, M_out)
    return cache[key]


KINDS = {"dense": Dense, "svd": SVD}


def fingerprint(run) -> dict:
    """What determines a propagator's map, as flat cache-key parts: the scheme's and the
    observation's class, matrices, arrays and numbers, and the number of steps."""
    plain = (np.ndarray, float, int, str, bool)
    parts = {"steps": run.steps}
    for name, obj in (("scheme", run.scheme), ("observation", run.observation)):
        parts[f"{name}.type"] = type(obj).__name__
        parts.update({f"{name}.{k}": v for k, v in vars(obj).items()
                      if sp.issparse(v) or isinstance(v, plain)})
    return parts


def build(kind: str, run, n_in: int, n_out: int, M=None, M_out=None, parts: dict | None = None,
          adjoint=None):
    """A compiled backend of ``kind`` ('dense' or 'svd') for the map ``run``, within the budget.

    With ``adjoint`` an SVD is first tried from products (:func:`.lowrank.svd_from_products`,
    about ``r + 32`` forward and ``r`` adjoint runs); once the rank passes ``(N − 32)/2`` the
    ``N`` runs of the dense ``P`` are cheaper and it is built from those instead.
    With ``parts`` (what determines the map, e.g. :func:`fingerprint` of the scheme and the
    observation) the arrays go through the disk cache (:mod:`pdeinv.util.cache`): a second run of
    the same scene loads them instead of stepping again.
    """
    need, have = KINDS[kind].nbytes(n_in, n_out) / 1e9, budget_gb()
    if need > have and not (kind == "svd" and adjoint is not None):
        raise ValueError(f"backend={kind!r} needs about {need:.2g} GB for a {n_out}×{n_in} operator; the "
                         f"budget is {have:g} GB (PDEINV_DENSE_BUDGET_GB); use backend='steps' or 'auto'")

    def make():
        if kind == "svd" and adjoint is not None:
            fits = need <= have
            per_rank = 3 * 8 * (n_in + n_out)  # Q, W, B and the factors, per singular value
            cap = (n_in - 32) // 2 if fits else int(have * 1e9 / per_rank)
            try:
                return svd_from_products(run, adjoint, n_in, n_out, M, M_out, SVD_RTOL, max_rank=cap)
            except RankTooHigh as err:
                if not fits:
                    raise ValueError(f"backend='svd' of this {n_out}×{n_in} operator has {err} and "
                                     f"would need more than the budget of {have:g} GB "
                                     "(PDEINV_DENSE_BUDGET_GB); use backend='steps' or 'auto'") from None
        P = matrix(run, n_in, n_out)
        if kind == "dense":
            return {"P": P}
        svd = SVD(P, M, M_out)
        return {a: vars(svd)[a] for a in SVD.ARRAYS}

    if parts is None:
        arrays = make()
    else:
        from ...util.cache import cached

        arrays = cached(f"compiled_{kind}", _key(parts, M, M_out, n_in, n_out), make)
    return Dense(arrays["P"]) if kind == "dense" else SVD.restore(arrays, M_out)


def _key(parts: dict, M, M_out, n_in: int, n_out: int) -> dict:
    return {**parts, "M": M, "M_out": M_out, "rtol": SVD_RTOL, "shape": [n_out, n_in]}


def in_cache(parts: dict, M, M_out, n_in: int, n_out: int) -> frozenset:
    """The compiled kinds whose arrays for this map are already in the disk cache (no build)."""
    from ...util.cache import has

    return frozenset(k for k in KINDS if has(f"compiled_{k}", _key(parts, M, M_out, n_in, n_out)))


def plan(step_flops: float, n_in: int, n_out: int, reversible: bool = False,
         cached: frozenset = frozenset(), modal: tuple[float, float] | None = None) -> tuple[str, str]:
    """``(kind, why)``: 'modal', 'steps', 'dense' or 'svd' by the flops of a training run (module
    docstring); the one backend chooser of every time-stepping operator.

    Per step ``b`` columns go forward and back, and a SIP step adds a local inverse: the filter in a
    spectral basis (SVD, modal: two applications), a CG solve of about ``2·cg_iterations``
    applications (stepping, dense), and for a ``reversible`` operator time reversal (stepping: two
    runs) or, compiled dense, the filter in its SVD (two applications of it, the SVD paid once).
    Stepping costs ``step_flops`` per column, dense ``2mN``, SVD ``2r(m + N)`` with
    ``r ≤ min(m, N)``, modal ``2k(m + N)`` with ``modal = (k, build flops)``
    (:func:`.modal.estimate`; None: not offered; where it is offered the SVD is not, being the same
    basis ``|g|``, ``Φ`` built at a higher cost) (BLAS flops discounted by :data:`BLAS_ADVANTAGE`);
    the build runs ``N`` columns of stepping, plus ``~4 m N min(m, N)`` for the SVD, and costs
    nothing for the kinds in ``cached`` (:func:`in_cache`). Steps and batch:
    :data:`EXPECT`, set for one block by :func:`expecting`.
    """
    e, blas = EXPECT, 1.0 / BLAS_ADVANTAGE
    cols, r = e["steps"] * e["batch"], min(n_in, n_out)
    apply = {"steps": step_flops, "dense": 2 * n_in * n_out * blas, "svd": 2 * r * (n_in + n_out) * blas}
    build = {"steps": 0.0, "dense": n_in * step_flops, "svd": n_in * step_flops + 4 * n_in * n_out * r * blas}
    if modal is not None:  # the SVD (in M-norms) of a symmetric final-field map *is* its modal form
        apply = {"modal": 2 * modal[0] * (n_in + n_out) * blas, **{k: apply[k] for k in ("steps", "dense")}}
        build = {"modal": modal[1], **{k: build[k] for k in ("steps", "dense")}}
    inverse = {k: (2 if k in ("svd", "modal") else 2 * e["cg_iterations"]) * a for k, a in apply.items()}
    if reversible:  # time reversal steps; a compiled dense map's inverse is the filter in its SVD
        inverse["steps"] = 2 * step_flops
        if "dense" in build:
            inverse["dense"] = 4 * r * (n_in + n_out) * blas
            build["dense"] += 4 * n_in * n_out * r * blas
    build = {k: 0.0 if k in cached else v for k, v in build.items()}
    cost = {k: build[k] + cols * (2 * apply[k] + inverse[k]) for k in apply}
    fits = {k: k not in KINDS or KINDS[k].nbytes(n_in, n_out) / 1e9 <= budget_gb() for k in cost}
    best = min((k for k in cost if fits[k]), key=cost.get)
    why = ", ".join(f"{k}≈{v:.2g}" + ("" if fits[k] else " (over budget)")
                    + (" (cached)" if k in cached else "") for k, v in cost.items())
    return best, f"auto: {best} (flops of {e['steps']} steps × {e['batch']} columns: {why})"
