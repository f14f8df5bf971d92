"""Data in the user's units: rescaled once on the way in, answered in the same units.

Networks compute in float32, whose normal range is ``1.2e-38 … 3.4e38``: a loss sums the squares of a
batch's ``B·N`` values, so observations of magnitude ``1e30`` (a field in µK², a concentration in
molecules per m³) overflow and ones of ``1e-100`` underflow, while float64 files hold both. For **linear**
physics ``P(c x) = c P x``: the rows are divided by a power of ten ``c`` (:func:`units_of`), the run trains
on ``x / c, y / c``, and the trained network is answered as ``f(y) = c · g(y / c)`` (:class:`InUnits`),
its posterior's scale times ``c``. Nonlinear physics has its own units (Allen–Cahn's wells at ±1): such
data must already be in them, and is refused otherwise.
"""

from __future__ import annotations

import math

import numpy as np
import torch

#: the largest magnitudes trained on as they are: their squares, summed over a batch of up to 1e8 values,
#: stay inside float32's normal range with room to spare (1e24 · 1e8 ≪ 3.4e38; 1e-24 · 1e-7 ≫ 1.2e-38)
AS_IS = (1e-12, 1e12)


def units_of(y: np.ndarray, operator=None, name: str = "data") -> float:
    """The factor ``c`` the rows are divided by: 1 when ``max |y|`` is within :data:`AS_IS` (all zeros
    included), else the power of ten nearest to it. ``operator`` nonlinear and ``c ≠ 1``: ``ValueError``.
    Rows (of a 2-D ``y``) whose largest magnitudes lie further apart than :data:`AS_IS` spans are in no one
    unit (float32 holds no batch of both): ``ValueError``, naming the two rows."""
    top = float(np.max(np.abs(y))) if np.size(y) else 0.0
    if np.ndim(y) == 2 and top > 0.0:
        peaks = np.max(np.abs(y), axis=1)
        low = int(np.argmin(np.where(peaks > 0, peaks, np.inf)))
        if peaks[low] < top / (AS_IS[1] / AS_IS[0]):  # divided: 1e300 × 1e24 overflowed (a warning)
            high = int(np.argmax(peaks))
            raise ValueError(f"{name} holds rows of magnitude {peaks[low]:.3g} (row {low}) and {top:.3g} "
                             f"(row {high}), more than {AS_IS[1] / AS_IS[0]:g} apart: the rows are not in "
                             "one unit; rescale them to one, or train on them separately")
    if top == 0.0 or AS_IS[0] <= top <= AS_IS[1]:
        return 1.0
    c = 10.0 ** round(math.log10(top))
    if operator is not None:
        from ..physics.nonlinear import is_linear

        if not is_linear(operator):
            raise ValueError(f"{name} holds values up to {top:.3g}: this problem's physics is nonlinear, so "
                             "its data must be in the problem's own units (magnitudes between "
                             f"{AS_IS[0]:g} and {AS_IS[1]:g}); rescale the data (e.g. divide by {c:g})")
    return c


class InUnits(torch.nn.Module):
    """``f(y) = c · g(y / c)``: the network ``g`` (``inner``), trained on rows divided by ``c`` (``units``),
    answered in the data's own units. The division and the product are in float64, so ``y`` and ``f(y)``
    may lie beyond float32's range; ``g`` runs in its own dtype."""

    def __init__(self, inner: torch.nn.Module, units: float):
        super().__init__()
        self.inner = inner
        self.register_buffer("units", torch.tensor(float(units), dtype=torch.float64))

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.inner((y.double() / self.units).to(input_dtype(self.inner))).double() * self.units


def input_dtype(model: torch.nn.Module) -> torch.dtype:
    """The dtype to feed ``model``: float64 for :class:`InUnits` (its rows may lie beyond float32's
    range), else its parameters' (float32 without any)."""
    if isinstance(model, InUnits):
        return torch.float64
    param = next(iter(model.parameters()), None)
    return param.dtype if param is not None else torch.float32


def wrap(model: torch.nn.Module, units: float) -> torch.nn.Module:
    """``model`` answered in units ``units`` (itself when they are 1)."""
    return model if units == 1.0 else InUnits(model, units)


def unwrap(model: torch.nn.Module) -> tuple[torch.nn.Module, float]:
    """``(g, c)`` of an :class:`InUnits` network; ``(model, 1.0)`` for any other."""
    return (model.inner, float(model.units)) if isinstance(model, InUnits) else (model, 1.0)


def in_units(model, posterior, record: dict, units: float):
    """``(model, posterior)`` of a run trained on rows divided by ``units``, answered in the data's units:
    :func:`wrap` the network, the posterior's scale and ``record``'s absolute figure (the posterior's
    ``width_90``) times ``units``; relative errors and coverages are as they are."""
    if units == 1.0:
        return model, posterior
    if posterior is not None:
        import dataclasses

        probe = {} if posterior.probe_y is None else {"probe_y": posterior.probe_y * units,
                                                      "probe_x": posterior.probe_x * units}
        posterior = dataclasses.replace(posterior, scale=posterior.scale * units, **probe)
    if "width_90" in record.get("posterior", {}):
        record["posterior"]["width_90"] *= units
    return wrap(model, units), posterior


def for_checks(y: np.ndarray, operator=None) -> float:
    """The factor a scale-free check (a relative noise level, a relative mismatch) divides the rows by
    before squaring them: :func:`units_of` where ``operator`` is linear or not given (``P(x/c) = P x / c``),
    else 1 (nonlinear physics keeps its own units; :func:`units_of` refuses such data later)."""
    if operator is not None:
        from ..physics.nonlinear import is_linear

        if not is_linear(operator):
            return 1.0
    return units_of(y)
