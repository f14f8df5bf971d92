"""A trained network's posterior, calibrated by split conformal prediction on held-out rows.

The network gives the mean ``μ(y) = f(y)``. What it does not know is measured on rows it never saw,
with their true fields ``x`` (prior draws, or a file's held-out rows), in two disjoint parts:

* **spread rows** fix the shape: the per-node scale ``σ_i``, the :data:`ROBUST` quantile of
  ``|x_bi − μ_bi|`` over the rows, and ``k`` normalized residuals ``z_j = (x_j − μ_j)/σ`` kept for samples;
* **conformal rows** fix the size: the signed scores ``s_bi = (x_bi − μ_bi)/σ_i``, pooled over rows and
  nodes, give the quantile function ``Q``, and the ball scores ``t_b = ‖x_b − μ_b‖_M / ‖σ‖_M`` their
  order statistics ``t_(1) ≤ … ≤ t_(n)``.

Then, for a new row exchangeable with the conformal rows (split conformal prediction; Vovk et al. 2005,
Angelopoulos & Bates 2021):

* the central interval at level ``α`` at node ``i`` is ``[μ_i + σ_i Q(q_lo), μ_i + σ_i Q(q_hi)]``,
  ``q_lo = ⌊(n+1)(1−α)/2⌋/n``, ``q_hi = ⌈(n+1)(1+α)/2⌉/n`` over the ``n`` pooled scores: it covers the
  true value of a node drawn at random with probability ≥ α, whatever the network;
* the credible L²(Ω) ball ``‖x − μ‖_M ≤ t_(⌈(n+1)α⌉) ‖σ‖_M`` covers the whole field with probability ≥ α;
* the reported std is ``σ_i · rms(s)``, the calibrated root-mean-square error at node ``i``;
* samples are the kept residuals, resampled: ``x = μ + σ ⊙ z_j``, ``j`` uniform over the ``k``. They
  carry the residuals' correlations and marginals as they are (a Gaussian copula of them broke the
  near-cancellations of smooth statistics, e.g. the field's mean, whose SBC p-value fell to 0.00–0.004
  on noise-free heat_1d); how many are kept bounds how well they are calibrated (about ``1/√k``).

The scale does not depend on ``y``: the intervals are as wide as the network's error over the prior,
which is narrower than the linear-Gaussian posterior's wherever the network beats the linear estimate.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from numbers import Real

import numpy as np

#: the per-node scale is this quantile of ``|x − μ|`` (a Gaussian's ±1 std; an rms would follow the few
#: rows of a heavy tail: 2048 rows of one run gave two halves 1.6× apart)
ROBUST = 0.6827

#: how far a network's mean on the probe row may be from the one stored (relative to its norm): float32
#: rounding and a folded input transform (``model.pt`` stores the folded map) change it by ~1e-6, a GPU's
#: TF32 convolutions by ~1e-3; another run's network differs by its own error (0.6 and 33 measured)
PROBE_RTOL = 1e-2

#: points of the stored quantile function (probabilities ``0, 1/(G−1), …, 1``); interpolated between
QUANTILE_POINTS = 4001


def _rms_norm(mass, v: np.ndarray) -> np.ndarray:
    """``‖v_b‖_M`` per row (``mass`` sparse ``(N, N)``, or ``None`` for the Euclidean norm)."""
    if mass is None:
        return np.linalg.norm(v, axis=1)
    return np.sqrt(np.maximum(np.einsum("bi,bi->b", v, (mass @ v.T).T), 0.0))


@dataclass(frozen=True)
class Calibration:
    """What the calibration stage fits (module docstring); arrays only, so it saves to one ``.npz``."""

    scale: np.ndarray        # (N,) σ_i
    residuals: np.ndarray    # (k, N) normalized residuals z_j of spread rows (float16: ~1e-3 of σ; float32
    #                          when one exceeds float16's range)
    quantiles: np.ndarray    # (QUANTILE_POINTS,) Q at 0, …, 1 of the pooled signed scores
    ball: np.ndarray         # (n,) sorted ball scores t_(1..n)
    pooled: int              # n·N: the number of pooled signed scores
    rms: float               # rms(s) of the pooled signed scores
    probe_y: np.ndarray | None = None  # (m,) one calibration row's observations, and the network's
    probe_x: np.ndarray | None = None  # (N,) mean for it: the network this posterior was fitted for

    @classmethod
    def fit(cls, spread: np.ndarray, conformal: np.ndarray, mass=None, keep: int = 256) -> Calibration:
        """From residuals ``x − μ`` of the spread rows and of the conformal rows (each ``(n, N)``); ``keep``
        normalized spread residuals are stored for samples."""
        spread, conformal = np.asarray(spread, float), np.asarray(conformal, float)
        if len(spread) < 2 or len(conformal) < 2:
            raise ValueError(f"calibration needs at least 2 spread and 2 conformal rows; got {len(spread)} "
                             f"and {len(conformal)}")
        scale = np.quantile(np.abs(spread), ROBUST, axis=0)  # the std of a Gaussian; robust to heavy tails
        scale = np.maximum(scale, 1e-12 * max(scale.max(), 1e-300))  # a node no residual reached
        z = spread[:keep] / scale
        z = z.astype(np.float16 if np.abs(z).max() < 6e4 else np.float32)  # float16 ends at 65 504
        scores = (conformal / scale).ravel()
        q = np.quantile(scores, np.linspace(0, 1, QUANTILE_POINTS))
        ball = np.sort(_rms_norm(mass, conformal) / _rms_norm(mass, scale[None])[0])
        return cls(scale, z, q, ball, scores.size, float(np.sqrt(np.mean(scores**2))))

    # -- what users read -----------------------------------------------------------------------------
    @property
    def std(self) -> np.ndarray:
        return self.scale * self.rms

    def _q(self, p):
        return np.interp(p, np.linspace(0, 1, QUANTILE_POINTS), self.quantiles)

    def interval(self, mean: np.ndarray, level: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
        """The central per-node interval at ``level`` (module docstring), ``(lo, hi)`` shaped as ``mean``."""
        level = _level(level)
        n = self.pooled
        lo = np.floor((n + 1) * (1 - level) / 2) / n
        hi = min(np.ceil((n + 1) * (1 + level) / 2) / n, 1.0)
        return mean + self.scale * self._q(lo), mean + self.scale * self._q(hi)

    def radius(self, level: float = 0.9) -> float:
        """``ρ`` of the credible L²(Ω) ball ``‖x − μ‖_M ≤ ρ``: ``t_(⌈(n+1)α⌉) ‖σ‖_M`` (in units of ``‖σ‖_M``
        here; :meth:`ball_radius` multiplies). ``inf`` when the rows are too few for ``level``."""
        level = _level(level)
        i = int(np.ceil((len(self.ball) + 1) * level))
        return float(self.ball[i - 1]) if i <= len(self.ball) else float("inf")

    def ball_radius(self, level: float = 0.9, mass=None) -> float:
        return self.radius(level) * float(_rms_norm(mass, self.scale[None])[0])

    def samples(self, mean: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
        """``k`` draws per row of ``mean`` ``(B, N)``: ``(B, k, N)`` (module docstring)."""
        mean = np.atleast_2d(mean)
        return self.drawn(mean, self.picks(len(mean), k, seed))

    def picks(self, rows: int, k: int, seed: int = 0) -> np.ndarray:
        """The kept residuals' indices ``(rows, k)`` that :meth:`samples` adds with ``seed``."""
        return np.random.default_rng(seed).integers(len(self.residuals), size=(rows, k))

    def drawn(self, mean: np.ndarray, pick: np.ndarray) -> np.ndarray:
        """The draws ``(B, k, N)`` of rows ``mean`` ``(B, N)`` with residual indices ``pick`` ``(B, k)``
        (:meth:`picks`): a part of the rows of :meth:`samples` at a time."""
        return mean[:, None, :] + self.scale * self.residuals[pick].astype(np.float64)

    def check_network(self, mean_of) -> None:
        """Refuse a network this posterior was not fitted for: ``mean_of(rows) -> (B, N)`` (the network's
        mean) must give back the stored probe row's mean, to :data:`PROBE_RTOL` of its norm. A posterior of
        another run of the same size gave that network's intervals with exit 0. No probe (a file of an
        earlier pdeinv): nothing to compare."""
        if self.probe_y is None or self.probe_x is None:
            return
        got = np.asarray(mean_of(self.probe_y[None]), dtype=float)[0]
        top = max(float(np.max(np.abs(self.probe_x))), np.finfo(float).tiny)  # data of 1e200: no squares
        ref = max(float(np.linalg.norm(self.probe_x / top)), 1e-300)
        gap = float(np.linalg.norm((got - self.probe_x) / top)) / ref
        if not gap <= PROBE_RTOL:
            raise ValueError(f"the posterior was fitted for another network (on its probe row this one's "
                             f"mean differs by {gap:.3g} of its norm); use the posterior of the same run "
                             "as the network (result.posterior, or load_posterior of the run it was loaded "
                             "from)")

    # -- files -----------------------------------------------------------------------------------------
    def to_bytes(self) -> bytes:
        buffer = io.BytesIO()
        probe = {} if self.probe_y is None else {"probe_y": self.probe_y, "probe_x": self.probe_x}
        np.savez(buffer, scale=self.scale, residuals=self.residuals,
                 quantiles=self.quantiles, ball=self.ball, pooled=self.pooled, rms=self.rms, **probe)
        return buffer.getvalue()

    @classmethod
    def load(cls, path) -> Calibration:
        """The calibration saved at ``path`` (:meth:`to_bytes`), checked (:meth:`check`)."""
        with np.load(path) as f:
            probe = (f["probe_y"], f["probe_x"]) if "probe_y" in f.files and "probe_x" in f.files else \
                (None, None)
            cal = cls(f["scale"], f["residuals"], f["quantiles"], f["ball"], int(f["pooled"]),
                      float(f["rms"]), *probe)
        return cal.check()

    def check(self) -> Calibration:
        """``self`` if its arrays are what :meth:`fit` makes (a ``ValueError`` naming the first that is not:
        an edited or foreign file gave reversed intervals or NaN error bars with exit 0)."""
        n = self.scale.shape[0] if self.scale.ndim == 1 else -1

        def finite(a):
            return bool(np.all(np.isfinite(a)))

        def rising(a):
            return bool(np.all(np.diff(a) >= 0))

        problems = [
            ("scale", n > 0 and finite(self.scale) and bool(np.all(self.scale > 0)),
             "a positive finite number per node"),
            ("residuals", self.residuals.ndim == 2 and self.residuals.shape[0] >= 1
             and self.residuals.shape[1] == n and finite(self.residuals),
             "at least one finite row of the nodes' normalized residuals"),
            ("quantiles", self.quantiles.shape == (QUANTILE_POINTS,) and finite(self.quantiles)
             and rising(self.quantiles), f"{QUANTILE_POINTS} finite non-decreasing values"),
            ("ball", self.ball.ndim == 1 and self.ball.size >= 1 and finite(self.ball)
             and bool(np.all(self.ball >= 0)) and rising(self.ball), "sorted finite non-negative scores"),
            ("pooled", self.pooled >= 1, "a count >= 1"),
            ("rms", np.isfinite(self.rms) and self.rms > 0, "a positive finite number"),
            ("probe_x", self.probe_x is None or (np.shape(self.probe_x) == (n,) and finite(self.probe_x)
                                                 and self.probe_y is not None and np.ndim(self.probe_y) == 1
                                                 and finite(self.probe_y)),
             "the network's finite mean for one finite row of observations")]
        for name, ok, expected in problems:
            if not ok:
                raise ValueError(f"its {name!r} is not {expected}")
        return self


def _level(level) -> float:
    """``level`` as a float in (0, 1); a string ('0.9') is a ``TypeError`` as any other non-number."""
    if isinstance(level, bool) or not isinstance(level, Real):
        raise TypeError(f"level={level!r:.60} is {type(level).__name__}; expected a number in (0, 1)")
    value = float(level)
    if not 0 < value < 1:
        raise ValueError(f"level={level!r} is not allowed; expected a number in (0, 1) (0.9: 90 % intervals)")
    return value
