"""What a user gets from a trained network and its calibrated posterior, in one batched forward pass.

``predictive(model, posterior, y)``: the mean ``x = f(y)``, the per-node ``std``, the central interval
``lo``, ``hi`` at ``level`` and, with ``samples=K``, ``K`` posterior draws per observation ``(B, K, N)``
(:class:`~pdeinv.posterior.conformal.Calibration`). ``pdeinv predict`` writes the same arrays.
"""

from __future__ import annotations

import numpy as np
import torch

from .. import _checks
from .._checks import batch
from ..problem.units import input_dtype
from ..util.memory import check
from .conformal import Calibration, _level


@torch.no_grad()
def forward(model, y: np.ndarray, chunk: int = 1024) -> np.ndarray:
    """``f(y)`` as float64 numpy ``(B, N)``, ``chunk`` rows at a time, in the model's dtype and device."""
    param = next(iter(model.parameters()), None)
    dtype = input_dtype(model)
    device = param.device if param is not None else None
    parts = [model(torch.as_tensor(y[i:i + chunk], dtype=dtype, device=device)).double().cpu().numpy()
             for i in range(0, len(y), chunk)]
    return np.concatenate(parts)


#: bytes per entry of ``samples`` ``(B, K, N)``: the float64 result and the two float64 temporaries that
#: make it (the residuals cast, then scaled; :meth:`~pdeinv.posterior.conformal.Calibration.samples`)
SAMPLE_BYTES = 3 * 8


def predictive(model, posterior, y, level: float = 0.9, samples: int = 0, seed: int = 0,
               problem=None) -> dict:
    """``{"x", "std", "lo", "hi"}`` (each ``(B, N)``), and ``"samples"`` ``(B, K, N)`` when ``samples=K`` > 0,
    for observations ``y`` ``(B, m)`` or ``(m,)``; ``posterior`` is ``result.posterior`` or
    :func:`pdeinv.io.runs.load_posterior`'s. With ``problem``, ``m`` is checked against
    ``problem.operator.n_out``; without, a width the network cannot take is a ``ValueError`` naming ``y``'s
    shape. ``samples`` whose ``(B, K, N)`` draws would not fit the memory budget
    (:mod:`pdeinv.util.memory`) are refused before any is drawn."""
    if not isinstance(model, torch.nn.Module):
        raise TypeError(f"model={_short(model)} is {type(model).__name__}; expected a torch.nn.Module (a "
                        "training Result's .model, or pdeinv.load_run's)")
    if posterior is None:
        raise ValueError("posterior=None: this network has no calibrated posterior (train it with the "
                         "calibration stage: Trainer(calibration='auto'), the default where the scene has a "
                         "prior)")
    if not isinstance(posterior, Calibration):
        raise TypeError(f"posterior={_short(posterior)} is {type(posterior).__name__}; expected a "
                        "pdeinv.posterior.Calibration (result.posterior, or "
                        "pdeinv.io.runs.load_posterior(run_dir))")
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 0:
        raise ValueError(f"samples={samples!r} is not allowed; expected a count >= 0 (0: no samples)")
    kept = len(posterior.residuals)
    if samples > kept:  # every sample is one of the kept residuals: more would repeat them
        raise ValueError(f"samples={samples} is not allowed: the posterior keeps {kept} residuals, each "
                         f"sample is one of them; expected at most {kept}")
    seed = _checks.seed(seed)  # numpy's generators take 0 .. 2³²−1, as every seed= of pdeinv
    if problem is not None:
        from ..problem.trained import trained_for

        trained_for(model, _checks.problem(problem))
    level = _level(level)
    y = _observations(y, None if problem is None else problem.operator.n_out)
    B, K, N = len(y), int(samples), posterior.scale.shape[0]
    check(SAMPLE_BYTES * B * K * N, f"predictive(samples={K}) ({B} x {K} x {N} float64 draws)",
          "ask for fewer samples, or pass fewer rows of y at a time")
    try:
        mean = forward(model, y)
    except RuntimeError as err:  # a width the network's layers refuse; anything else is not y's fault
        first = (str(err).strip().splitlines() or [""])[0][:120]
        if "shape" not in first and "size" not in first:
            raise
        raise ValueError(f"y has shape {y.shape}; the network does not take {y.shape[1]} observations per "
                         f"row ({first}); expected (B, m), m the observations per row it was trained on "
                         "(problem.operator.n_out)") from None
    if mean.shape[1] != posterior.scale.shape[0]:
        raise ValueError(f"the network gives {mean.shape[1]} unknowns; the posterior is for "
                         f"{posterior.scale.shape[0]}: not this network's")
    posterior.check_network(lambda rows: forward(model, rows))
    lo, hi = posterior.interval(mean, level)
    out = {"x": mean, "std": np.broadcast_to(posterior.std, mean.shape).copy(), "lo": lo, "hi": hi}
    if samples:
        out["samples"] = posterior.samples(mean, K, seed)
    return out


def _observations(y, width: int | None) -> np.ndarray:
    """``y`` as a float64 ``(B, m)`` array (a ``(m,)`` row a batch of one; a tensor as numpy), finite;
    ``m`` is ``width`` when given, else ``y``'s own (the network checks it)."""
    if isinstance(y, torch.nn.Module):
        raise TypeError("y is a network; the arguments are predictive(model, posterior, y): swapped?")
    Y = y.detach().cpu().numpy() if isinstance(y, torch.Tensor) else np.asarray(y)
    if width is None and Y.ndim in (1, 2) and Y.size:
        width = Y.shape[-1]
    if width is None:
        raise ValueError(f"y has shape {Y.shape}; expected observations (B, m) or (m,)")
    return batch(Y, width, "y")[0]


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 and "\n" not in text else type(value).__name__
