"""Cost of one update step per rule, measured interleaved on the same network and batch.

``sip_vs_gd_step`` = SIP step / GD (Adam) step: SIP adds one forward and one local
inverse to the network's forward/backward, GD one forward and one adjoint.
``hig_step_s``: one HIG step (per-sample Jacobians ``∂y/∂θ`` of network + physics,
their Gram matrix or SVD, the half-inverse update), with the Jacobian's shape and
float64 size, the part of HIG's cost that GD and SIP never pay.
"""

from __future__ import annotations

import copy

import torch

from ..methods import GD, HIG, SIP, adam
from .timing import best, interleaved


def _stepper(rule, problem, model, y):
    model = copy.deepcopy(model)
    state = [rule.init(problem, model)]

    def step():
        state[0], _ = rule.step(state[0], model, y)

    return step


def step_ratios(problem, model, hig_model, batch: int = 32, hig_batch: int = 1,
                repeats: int = 5, seed: int = 0) -> dict:
    """Interleaved step timings (minimum over ``repeats``); ``model`` is copied, not trained."""
    _, y = problem.sample(max(batch, hig_batch), seed)
    y = torch.as_tensor(y, dtype=torch.float32)
    gd = _stepper(GD(optimizer=adam(1e-4)), problem, model, y[:batch])
    sip = _stepper(SIP(optimizer=adam(1e-4)), problem, model, y[:batch])
    t = interleaved({"gd": gd, "sip": sip}, repeats)
    t_gd, t_sip = t["gd"], t["sip"]
    hig = _stepper(HIG(eta=1e-3, tau=1e-5), problem, hig_model, y[:hig_batch])
    gd_small = _stepper(GD(optimizer=adam(1e-4)), problem, hig_model, y[:hig_batch])
    gd_small()
    t_gd_small = best(gd_small, repeats)
    t_hig = best(hig, max(1, repeats // 2))
    rows = hig_batch * problem.operator.n_out
    n_params = sum(p.numel() for p in hig_model.parameters() if p.requires_grad)
    return {"gd_step_s": t_gd, "sip_step_s": t_sip, "sip_vs_gd_step": t_sip / t_gd,
            "hig_step_s": t_hig, "gd_step_s_hig_net": t_gd_small, "hig_jacobian": [rows, n_params],
            "hig_jacobian_mb": rows * n_params * 8 / 2**20, "step_batch": batch, "hig_batch": hig_batch}
