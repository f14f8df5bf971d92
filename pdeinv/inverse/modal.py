"""Local inverse in a spectral basis: the Tikhonov filter ``g/(g² + α)`` per mode.

Written for the modal backend ``P = Φ diag(g) ΦᵀM`` (``ΦᵀMΦ = I``, ``g = r(dt μ)ⁿ`` on the
kept modes, :mod:`pdeinv.physics.backends.modal`); any :class:`~pdeinv.physics.capabilities.Spectral`
basis (a compiled SVD) works the same way with ``proj``, ``synth`` in place of ``MΦ``, ``Φ``. The
regularized change

    Δx = argmin ½‖PΔx − (y − y₀)‖²_M + ½α‖Δx‖²_M,      y₀ = P x₀,

is diagonal in modal coordinates ``c = ΦᵀM(y − y₀)``:

    Δx = Φ (g/(g² + α) ⊙ c),      returned: x₀ + Δx.

Components of ``y − y₀`` outside span Φ (the dropped modes, ``|g| < tol·max|g|``)
cannot be fitted: there the minimizer has ``Δx = 0``, which is the filter's value
to the modal tolerance. Per mode the recovered change is ``g²/(g²+α)`` times the
true one: a relative bias ``α/(g²+α)`` (Holl et al. 2022, heat inverse as a
spectral filter; Engl, Hanke, Neubauer, *Regularization of Inverse Problems*, §5).

Cost: one forward for ``y₀`` (2 products ``(B,N)·(N,k)``; none when the caller passes ``y₀``,
:meth:`SpectralTikhonov.local`), one projection and one synthesis: 2× one batched modal forward.
(Using ``ΦᵀMy₀ = g ⊙ ΦᵀMx₀`` would save a quarter, but then ``y = y₀`` leaves a rounding residue
``(ΦᵀMΦ − I)``, amplified by up to ``1/(2√α)`` — 1.3e-10 relative at α = 1e-12 — whereas ``y − y₀`` computed
by the same forward is exactly zero.) The discrepancy principle is applied to the part of the
data the filter can fit (the projected problem): with ``c`` the coordinates of ``y − y₀`` in the
basis (orthonormal in the observation norm) the residual and the noise it is compared with are

    ρ(α)² = Σ_k (α/(g_k²+α))² c_k²,        E‖ε‖² over the basis = σ² Σ_k ‖proj_k‖²,

both in closed form. The part of ``y − y₀`` outside span Φ is left out of both: no α changes
it, and counting it (as the full residual does) would let its own fluctuation decide α: on a few percent
of samples the unfittable part alone exceeds τ times the expected noise and α falls to its floor
(``tests/test_inverse.py``).
"""

from __future__ import annotations

import numpy as np

from ..physics.capabilities import Spectral, modal_basis
from ._inputs import given_forward, out, pair
from .alpha import Fit, as_rule


class SpectralTikhonov:
    """``P⁻¹_(x₀, Px₀)(y) = x₀ + synth (g/(g²+α) ⊙ c)``, ``c = (y − Px₀) proj``, for any operator
    with a spectral basis ``op.modes`` or one given as ``modes`` (``g``, ``proj``, ``out``, ``synth``,
    ``mass_out``; :class:`~pdeinv.physics.backends.compiled.LazySVD` for a dense forward):
    the modal heat backend (``proj = MΦ``, ``out = synth = Φ``) or a compiled SVD
    (:mod:`pdeinv.physics.backends.compiled`: ``proj = L_o U``, ``out = L_o⁻ᵀ U``, ``synth = L⁻ᵀ V``).

    ``alpha``: a number (absolute α) or a rule (:class:`~.alpha.Discrepancy`,
    :class:`~.alpha.RelativeAlpha`). After each call ``last_info`` holds the α used. Declares
    :class:`~.protocol.ReusesForward`: :meth:`local` takes ``P x₀`` from the caller.
    """

    def __init__(self, op, alpha, modes=None):
        backend = modal_basis(op) if modes is None else modes
        if not isinstance(backend, Spectral):
            raise ValueError(f"ModalTikhonov needs an operator with a modal backend or another spectral "
                             f"basis (op.modes, a pdeinv.physics.capabilities.Spectral); got {op!r}; "
                             "use TikhonovCG")
        self.op, self.modes = op, backend
        self.rule = as_rule(alpha)
        self.last_info: dict = {}

    @property
    def scale(self) -> float:
        """``max g²``, the unit of a relative α (read when first asked: ``modes`` may be lazy)."""
        return float(np.max(self.modes.g**2))

    def __call__(self, y, x0) -> np.ndarray:
        Y, X0, single = pair(y, x0, self.op.n_out, self.op.n_in)
        return out(self._step(Y, X0, self.op.forward(X0)), single)

    def local(self, y, x0, y0) -> np.ndarray:
        """``self(y, x0)`` given ``y0 = op.forward(x0)`` (:class:`~.protocol.ReusesForward`): no forward."""
        Y, X0, single = pair(y, x0, self.op.n_out, self.op.n_in)
        return out(self._step(Y, X0, given_forward(y0, X0, self.op.n_out)), single)

    def _step(self, Y, X0, Y0) -> np.ndarray:
        g = self.modes.g
        R = Y - Y0
        c = R @ self.modes.proj
        noise_trace = float((self.modes.proj**2).sum())  # E‖ε‖² over the basis / σ² (module docstring)
        alpha = self.rule.select(Fit(self._residual(c), Y, noise_trace, self.scale))
        self.last_info = {"alpha": alpha}
        return X0 + (g / (g**2 + alpha[:, None]) * c) @ self.modes.synth.T

    def _residual(self, c):
        """``ρ(α)`` of the projected problem (module docstring)."""
        g2 = self.modes.g**2

        def rho(alpha):
            return np.sqrt(((alpha[:, None] / (g2 + alpha[:, None]) * c) ** 2).sum(axis=1))

        return rho

    def __repr__(self):
        return f"{type(self).__name__}(k={len(self.modes.g)}, alpha={self.rule!r})"


#: the name from when only the modal heat backend had a spectral basis
ModalTikhonov = SpectralTikhonov
