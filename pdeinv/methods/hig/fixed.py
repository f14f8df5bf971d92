"""HIG's Kronecker step on rows it has taken before (the full batch): no feature map, no physics, no B.

With the notation of :mod:`.hig_kron` (``x_i = D(W̃ z̃_i)``, ``P̂ = P D = Q_C diag(s) Vᵀ``), the rows'
Gram ``G = Z̃ᵀZ̃ = W diag(a) Wᵀ`` (kept rank), ``Q_A = Z̃ W a^-½`` and the rows' targets ``Y*``, the
residual ``R = Z̃ W̃ᵀ P̂ᵀ − Y*`` enters the step only through

    M = Q_Aᵀ R Q_C = A₁ W̃ᵀ V diag(s) − M*,    A₁ = Q_Aᵀ Z̃ = a^½ Wᵀ,    M* = Q_Aᵀ Y* Q_C,
    ½ Σ_i ‖r_i‖² = ½ (‖M‖² + ‖Y* − Q_A M* Q_Cᵀ‖²)

(the last term is the targets' part that no ``W̃`` reaches: outside ``range(Z̃) ⊗ range(P̂)``).
:class:`FixedRows` keeps ``A₁``, ``M*``, that constant and ``S`` for the run; the step is then
``ΔW̃ = −η V diag(s) (M ⊙ S)ᵀ A₁``, two products, whatever the number of rows.

**Carrying M.** An applied step ``c·ΔW̃`` (``c``: the guard's multiplier) changes ``M`` by

    c·ΔM,   ΔM = A₁ ΔW̃ᵀ V diag(s) = −η diag(a) (M ⊙ S) diag(s²)     (A₁A₁ᵀ = diag(a), VᵀV = I),

so :class:`Carried` updates ``M`` elementwise and recomputes it exactly (two float64 products) every
:data:`REFRESH` steps and whenever the weights moved otherwise than by a multiple of the last step
(a roll-back to an older state, a resumed run, an edit): checked on the weights to 64 ulps.

**Dead features.** A feature column of ``Z̃`` that is zero on every row (a whitened direction the
whitening dropped: gain 0) has a zero column in every ``J_i``, so ``ΔW̃`` is zero there: ``G``, ``W`` and
``A₁`` are taken on the live columns only (``G``'s zero rows are exact, so this is the same step), and
the second product shrinks by the dead fraction. When the live features are uncorrelated to rounding
(every correlation ``|G_ij|/√(G_ii G_jj)`` ≤ :data:`UNCORRELATED`, 1e-10: the whitening fitted on these
rows with a noise floor makes them so, while the noise-free whitening's trailing directions carry
rounding), ``W = I``: ``A₁ = a^½`` is diagonal and the second product is a column scaling.

**Work a step does not need.** ``‖ΔW̃‖² = η² Σ_kl (M ⊙ S)²_kl a_k c_l`` (``V`` and ``W`` orthonormal) is
known before any product, per observation mode ``l``. A step whose norm is below the weights' resolution
(``‖ΔW̃‖ ≤ ε‖W̃‖``, ε the weights' machine epsilon: it changes the network's output by less than the
rounding of evaluating it) is not computed: the direction is ``None`` and ``M`` keeps its value
(noise-free wave_2d gets there within the preset's 1000 steps). The weakest modes, whose energies add up
to at most ``(u‖ΔW̃‖)²`` (``u`` the unit roundoff of the products: float32's 6e-8, below the products'
own rounding), are left out of the products and stay in ``M``.

**float32 products.** Above :data:`FLOAT32_ABOVE` multiply-adds ``ΔW̃``'s two products run in float32
(half the time of float64 on one core); their rounding,
~1e-6 of the step, reaches ``M`` at the next refresh and the iteration corrects it like any other
residual. ``M`` itself is always computed in float64 (it is a small difference of large terms).

Equal to the route that forms the features and runs the physics (``tests/test_hig_kron.py``).
The carried ``M`` lives in the rule's context, not in a checkpoint (the guard would copy it every
step): a resumed run recomputes it, and so agrees with the uninterrupted one to rounding, not bitwise
— the one exception to :mod:`pdeinv.training.checkpoint`'s bitwise resume (``tests/test_checkpoint.py``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg import blas

from ...inverse.decoder import DecodedSVD
from .kron import kept_spectrum, rank

#: steps between exact recomputations of the carried ``M`` (module docstring): 2 float64 products each
REFRESH = 50
#: ``k_out·r·k̃`` above which ``ΔW̃``'s products run in float32 (wave_2d: 9e8; heat_2d's reduced network: 7e7)
FLOAT32_ABOVE = 2e8
#: the largest correlation between two features for which ``G`` is taken as diagonal (:func:`uncorrelated`)
UNCORRELATED = 1e-10


class FixedRows(NamedTuple):
    """What the step needs from the rows, for the run (module docstring)."""

    a: np.ndarray  # the kept eigenvalues of G = Z̃ᵀZ̃ on the live columns (rank)
    A1: np.ndarray  # Q_Aᵀ Z̃ = a^½ Wᵀ on the columns ``cols`` (rank × cols), or a^½ (rank) when W = I
    cols: np.ndarray  # the columns of Z̃ (and W̃) that A₁ maps to: the live ones, or the kept ones if W = I
    M_goal: np.ndarray  # M* = Q_Aᵀ Y* Q_C (rank × r)
    rest: float  # ‖Y* − Q_A M* Q_Cᵀ‖²
    rows: int
    Vs: np.ndarray  # V diag(s) (k_out × r), float64
    S: np.ndarray  # S_kl (rank × r), 0 where dropped
    AC: np.ndarray  # a_k c_l (rank × r): ΔM = −η (M ⊙ S ⊙ AC) per unit step (module docstring)
    info: dict  # what the spectrum kept (route, kept, sigma_max, sigma_min_kept)
    fast: tuple  # (V diag(s), A₁) in the dtype of ΔW̃'s products

    @classmethod
    def of(cls, fac: DecodedSVD, Z: np.ndarray, goal: np.ndarray, a: np.ndarray, W: np.ndarray,
           tau: float, exponent: float) -> FixedRows:
        """From the rows' features ``Z̃`` (float64), targets ``goal`` and ``G``'s eigenpairs ``(a, W)``
        (recomputed on the live columns when some are dead; ``W = I`` when they are uncorrelated)."""
        live = np.flatnonzero(np.any(Z != 0, axis=0))
        Z = Z[:, live] if len(live) < Z.shape[1] else Z
        G = Z.T @ Z
        if uncorrelated(G):  # W = I: A₁ = a^½ is diagonal and ΔW̃ needs one product
            a = np.diag(G).copy()
            cols = np.flatnonzero(a > a.max() * max(Z.shape) * np.finfo(float).eps)  # hig_kron.rank
            a = a[cols]
            root = np.sqrt(a)
            QA, A1 = Z[:, cols] / root, root
        else:
            if len(live) < len(a):
                a, W = np.linalg.eigh(G)
            a, W = rank(a, W, Z.shape)
            root, cols = np.sqrt(a), np.arange(Z.shape[1])
            QA, A1 = Z @ (W / root), root[:, None] * W.T
        GQ = goal @ fac.Q
        M_goal = QA.T @ GQ
        rest = float(np.sum((goal - GQ @ fac.Q.T) ** 2) + np.sum((GQ - QA @ M_goal) ** 2))
        Vs = fac.V * fac.s
        S, info = kept_spectrum(fac, a, tau, exponent)
        dtype = np.float32 if Vs.shape[0] * Vs.shape[1] * len(a) > FLOAT32_ABOVE else np.float64
        return cls(a, A1, live[cols], M_goal, rest, len(Z), Vs, S, a[:, None] * (fac.s**2)[None, :], info,
                   (Vs.astype(dtype), A1.astype(dtype)))

    @property
    def runs(self) -> list[tuple[int, int, int]]:
        """``cols`` as runs of consecutive columns ``(start, stop, offset in cols)`` (``cols`` ascends)."""
        breaks = np.flatnonzero(np.diff(self.cols) != 1) + 1
        return [(int(self.cols[i]), int(self.cols[j - 1]) + 1, int(i))
                for i, j in zip([0, *breaks], [*breaks, len(self.cols)], strict=True)]

    def residual(self, weight: np.ndarray) -> np.ndarray:
        """``M = A₁ W̃ᵀ V diag(s) − M*`` at ``weight`` (``W̃``: ``k_out × k̃``, the bias as last column)."""
        W = np.concatenate([weight[:, start:stop] for start, stop, _ in self.runs], axis=1)
        WV = W.T @ self.Vs
        return (self.A1[:, None] * WV if self.A1.ndim == 1 else self.A1 @ WV) - self.M_goal

    def loss(self, M: np.ndarray) -> float:
        """``½ mean_i ‖r_i‖²`` from ``M`` (module docstring)."""
        return 0.5 * (float(np.vdot(M, M)) + self.rest) / self.rows


def uncorrelated(G: np.ndarray) -> bool:
    """Whether the features are uncorrelated to rounding: ``|G_ij| ≤`` :data:`UNCORRELATED` ``·√(G_ii G_jj)``
    for ``i ≠ j`` (then ``W = I`` up to that relative perturbation of the step, far below τ and the
    float32 products' rounding)."""
    d = np.sqrt(np.diag(G))
    if not (d > 0).all():
        return False
    C = np.abs(G) / d[:, None] / d[None, :]
    np.fill_diagonal(C, 0.0)
    return float(C.max(initial=0.0)) <= UNCORRELATED


def _axpy(a: float, x: np.ndarray, y: np.ndarray) -> None:
    """``y += a·x`` in place, one pass, no temporary (BLAS axpy; C-contiguous arrays of one shape and
    dtype)."""
    if not (x.flags.c_contiguous and y.flags.c_contiguous and x.dtype == y.dtype and x.shape == y.shape):
        raise ValueError("axpy needs C-contiguous arrays of one shape and dtype")
    blas.get_blas_funcs("axpy", (x, y))(x.reshape(-1), y.reshape(-1), a=a)


class Carried:
    """``M`` carried from step to step (module docstring): the weights and the step it last gave.

    The step is written into one buffer (``k_out × k̃``, float64, zero on the dead columns) that the
    returned direction shares: it is valid until the next :meth:`step`."""

    def __init__(self, fixed: FixedRows):
        self.fixed, self.weight, self.M, self.dM, self.age = fixed, None, None, None, 0
        self.delta = self.coef = self.norm = self.dd = None

    def residual(self, weight: np.ndarray) -> np.ndarray:
        """``M`` at ``weight``: carried when ``weight − last = c·step`` (to 64 ulps), else computed."""
        if self.M is not None and self.age < REFRESH and weight.shape == self.weight.shape:
            D = np.subtract(weight, self.weight, out=self.weight)  # the last weights are not needed again
            c = float(np.vdot(D, self.delta)) / self.dd if self.dd > 0 else 0.0
            _axpy(-c, self.delta, D)
            bound = self.norm + abs(c) * self.dd**0.5  # ≥ ‖weight‖ when it passes (triangle inequality)
            if float(np.linalg.norm(D)) <= 64 * np.finfo(weight.dtype).eps * bound:
                self.age, self.norm = self.age + 1, bound
                _axpy(c * self.coef, self.dM, self.M)
                return self.M
        self.age, self.norm = 0, float(np.linalg.norm(weight))
        return self.fixed.residual(weight.astype(float, copy=False))

    def step(self, weight: np.ndarray, eta: float, unit: float) -> tuple[np.ndarray | None, float]:
        """``(unit · ΔW̃, loss)`` at ``weight`` (a fresh array this object keeps), remembered for the next
        call; ``ΔW̃`` is ``None`` when it is below the weights' resolution (module docstring)."""
        f = self.fixed
        weight = np.ascontiguousarray(weight)
        M = self.residual(weight)
        self.weight, self.M, self.coef = weight, M, -eta * unit
        MS = M * f.S
        dM = MS * f.AC  # ΔM per unit of coef; also ‖ΔW̃‖² = coef² Σ_kl MS·dM (V, W orthonormal)
        # ΔW̃'s energy per observation mode l (coef·coef, not coef**2: a float's power raises OverflowError)
        energy = np.einsum("kl,kl->l", MS, dM) * self.coef * self.coef
        total = float(energy.sum())
        if not total > (np.finfo(weight.dtype).eps * self.norm) ** 2:  # nothing the weights can resolve
            self.dd = 0.0
            return None, f.loss(M)
        Vs, A1 = f.fast
        rows = _modes(energy, total, np.finfo(Vs.dtype).eps / 2)
        if len(rows) < len(energy):  # the modes below the products' rounding: not applied, M keeps them
            Vs, MS, dM[:, np.setdiff1d(np.arange(len(energy)), rows)] = Vs[:, rows], MS[:, rows], 0.0
        X = np.multiply(MS, self.coef, dtype=Vs.dtype).T  # r × rank; the cheaper order of V diag(s) · X · A₁
        if A1.ndim == 1:
            prod = Vs @ X
            prod *= A1
        else:
            (k, r), (kept, kt) = Vs.shape, A1.shape
            prod = (Vs @ X) @ A1 if k * kept * (r + kt) <= r * kt * (kept + k) else Vs @ (X @ A1)
        if self.delta is None or self.delta.shape != weight.shape or self.delta.dtype != weight.dtype:
            self.delta = np.zeros(weight.shape, weight.dtype)  # the dead columns stay zero
        for start, stop, at in f.runs:  # slices: a fancy-indexed column write costs 20× more
            self.delta[:, start:stop] = prod[:, at:at + stop - start]
        self.dd, self.dM = float(np.vdot(self.delta, self.delta)), dM
        return self.delta, f.loss(M)


def _modes(energy: np.ndarray, total: float, u: float) -> np.ndarray:
    """The observation modes ``l`` whose part of ``ΔW̃`` is computed: all but the weakest, whose energies
    add up to at most ``(u · ‖ΔW̃‖)²`` (``u``: the unit roundoff of the products), in index order."""
    order = np.argsort(energy)
    weak = int(np.searchsorted(np.cumsum(energy[order]), u * u * total, side="right"))
    return np.sort(order[weak:])
