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

**float32 products.** Above :data:`FLOAT32_ABOVE` multiply-adds ``ΔW̃``'s two products run in float32
(half the time on one core: 0.049 s against 0.099 s for a 961³ product, measured); their rounding,
~1e-6 of the step, reaches ``M`` at the next refresh and the iteration corrects it like any other
residual. ``M`` itself is always computed in float64 (it is a small difference of large terms).

Equal to the route that forms the features and runs the physics (``tests/test_hig_kron.py``).
The carried ``M`` lives in the rule's context, not in a checkpoint (the guard would copy it every
step): a resumed run recomputes it, and so agrees with the uninterrupted one to rounding, not bitwise
— the one exception to :mod:`pdeinv.checkpoint`'s bitwise resume (``tests/test_checkpoint.py``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..inverse.decoder import DecodedSVD
from .hig_kron import kept_spectrum, rank

#: steps between exact recomputations of the carried ``M`` (module docstring): 2 float64 products each
REFRESH = 50
#: ``k_out·r·k̃`` above which ``ΔW̃``'s products run in float32 (wave_2d: 9e8; heat_2d's reduced network: 7e7)
FLOAT32_ABOVE = 2e8


class FixedRows(NamedTuple):
    """What the step needs from the rows, for the run (module docstring)."""

    a: np.ndarray  # the kept eigenvalues of G = Z̃ᵀZ̃ (rank)
    A1: np.ndarray  # Q_Aᵀ Z̃ = a^½ Wᵀ (rank × k̃), float64
    M_goal: np.ndarray  # M* = Q_Aᵀ Y* Q_C (rank × r)
    rest: float  # ‖Y* − Q_A M* Q_Cᵀ‖²
    rows: int
    Vs: np.ndarray  # V diag(s) (k_out × r), float64
    S: np.ndarray  # S_kl (rank × r), 0 where dropped
    c: np.ndarray  # s², the eigenvalues of P̂P̂ᵀ (r)
    info: dict  # what the spectrum kept (route, kept, sigma_max, sigma_min_kept)
    fast: tuple  # (V diag(s), A₁) in the dtype of ΔW̃'s products

    @classmethod
    def of(cls, fac: DecodedSVD, Z: np.ndarray, goal: np.ndarray, a: np.ndarray, W: np.ndarray,
           tau: float, exponent: float) -> FixedRows:
        """From the rows' features ``Z̃`` (float64), targets ``goal`` and ``G``'s eigenpairs ``(a, W)``."""
        a, W = rank(a, W, Z.shape)
        root = np.sqrt(a)
        QA = Z @ (W / root)
        GQ = goal @ fac.Q
        M_goal = QA.T @ GQ
        rest = float(np.sum((goal - GQ @ fac.Q.T) ** 2) + np.sum((GQ - QA @ M_goal) ** 2))
        A1, Vs = root[:, None] * W.T, fac.V * fac.s
        S, info = kept_spectrum(fac, a, tau, exponent)
        dtype = np.float32 if Vs.shape[0] * Vs.shape[1] * A1.shape[1] > FLOAT32_ABOVE else np.float64
        return cls(a, A1, M_goal, rest, len(Z), Vs, S, fac.s**2, info, (Vs.astype(dtype), A1.astype(dtype)))

    def residual(self, weight: np.ndarray) -> np.ndarray:
        """``M = A₁ W̃ᵀ V diag(s) − M*`` at ``weight`` (``W̃``: ``k_out × k̃``, the bias as last column)."""
        return self.A1 @ (weight.T @ self.Vs) - self.M_goal

    def loss(self, M: np.ndarray) -> float:
        """``½ mean_i ‖r_i‖²`` from ``M`` (module docstring)."""
        return 0.5 * (float(np.sum(M**2)) + self.rest) / self.rows


class Carried:
    """``M`` carried from step to step (module docstring): the weights and the step it last gave."""

    def __init__(self, fixed: FixedRows):
        self.fixed, self.weight, self.delta, self.M, self.dM, self.age = fixed, None, None, None, None, 0

    def residual(self, weight: np.ndarray) -> np.ndarray:
        """``M`` at ``weight``: carried when ``weight − last = c·step`` (to 64 ulps), else computed."""
        if self.M is not None and self.age < REFRESH and weight.shape == self.weight.shape:
            D = np.subtract(weight, self.weight, out=self.weight)  # the last weights are not needed again
            c = float(np.vdot(D, self.delta)) / self.dd if self.dd > 0 else 0.0
            D -= c * self.delta
            ulp = 64 * np.finfo(weight.dtype).eps
            if np.linalg.norm(D) <= ulp * (self.norm + abs(c) * self.dd**0.5):
                self.age += 1
                return self.M + c * self.dM
        self.age = 0
        return self.fixed.residual(weight.astype(float, copy=False))

    def step(self, weight: np.ndarray, eta: float, unit: float) -> tuple[np.ndarray, float]:
        """``(unit · ΔW̃, loss)`` at ``weight``, remembered for the next call."""
        f = self.fixed
        M = self.residual(weight)
        MS = M * f.S
        Vs, A1 = f.fast
        X = MS.astype(Vs.dtype).T  # r × rank; the cheaper order of V diag(s) · X · A₁
        (k, r), (kept, kt) = Vs.shape, A1.shape
        delta = (Vs @ X) @ A1 if k * kept * (r + kt) <= r * kt * (kept + k) else Vs @ (X @ A1)
        delta *= -eta * unit
        self.weight, self.M, self.norm = weight.copy(), M, float(np.linalg.norm(weight))
        self.delta = delta.astype(weight.dtype)
        self.dd = float(np.vdot(self.delta, self.delta))
        self.dM = (-eta * unit) * (f.a[:, None] * MS * f.c[None, :])
        return self.delta, f.loss(M)
