"""What a user gets from a trained network and its calibrated posterior, in one batched forward pass.

``predictive(model, posterior, y)``: the mean ``x = f(y)``, the per-node ``std``, the central interval
``lo``, ``hi`` at ``level`` and, with ``samples=K``, ``K`` posterior draws per observation ``(B, K, N)``
(:class:`~pdeinv.posterior.conformal.Calibration`). ``pdeinv predict`` writes the same arrays.
"""

from __future__ import annotations

import numpy as np
import torch

from ..problem.units import input_dtype


@torch.no_grad()
def forward(model, y: np.ndarray, chunk: int = 1024) -> np.ndarray:
    """``f(y)`` as float64 numpy ``(B, N)``, ``chunk`` rows at a time, in the model's dtype and device."""
    param = next(iter(model.parameters()), None)
    dtype = input_dtype(model)
    device = param.device if param is not None else None
    parts = [model(torch.as_tensor(y[i:i + chunk], dtype=dtype, device=device)).double().cpu().numpy()
             for i in range(0, len(y), chunk)]
    return np.concatenate(parts)


def predictive(model, posterior, y, level: float = 0.9, samples: int = 0, seed: int = 0) -> dict:
    """``{"x", "std", "lo", "hi"}`` (each ``(B, N)``), and ``"samples"`` ``(B, K, N)`` when ``samples=K`` > 0,
    for observations ``y`` ``(B, m)``; ``posterior`` is ``result.posterior`` or
    :func:`pdeinv.io.runs.load_posterior`'s."""
    if posterior is None:
        raise ValueError("posterior=None: this network has no calibrated posterior (train it with the "
                         "calibration stage: Trainer(calibration='auto'), the default where the scene has a "
                         "prior)")
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 0:
        raise ValueError(f"samples={samples!r} is not allowed; expected a count >= 0 (0: no samples)")
    y = np.atleast_2d(np.asarray(y, dtype=np.float64))
    mean = forward(model, y)
    if mean.shape[1] != posterior.scale.shape[0]:
        raise ValueError(f"the network gives {mean.shape[1]} unknowns; the posterior is for "
                         f"{posterior.scale.shape[0]}: not this network's")
    lo, hi = posterior.interval(mean, level)
    out = {"x": mean, "std": np.broadcast_to(posterior.std, mean.shape).copy(), "lo": lo, "hi": hi}
    if samples:
        out["samples"] = posterior.samples(mean, int(samples), seed)
    return out
