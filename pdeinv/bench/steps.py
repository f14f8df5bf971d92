"""Cost of one update step per rule: the presets on the default network, interleaved on the same batch.

``sip_vs_gd_step`` = SIP step / GD (Adam) step: SIP adds one forward and one local inverse to the
network's forward/backward, GD one forward and one adjoint. ``hig_step_s``: one step of ``--method
hig`` (the half-inverse update on the route the network and operator declare: the Kronecker route on
the whitened linear default), with the shape and float64 size of the stacked Jacobian ``∂y/∂θ`` that
a dense route would build, the part of HIG's cost that GD and SIP never pay.
"""

from __future__ import annotations

import copy

import torch

from ..methods.presets import make_rule
from .timing import interleaved


def _stepper(method, problem, model, y):
    rule = make_rule(method, problem, problem.noise)[0]
    model = copy.deepcopy(model)
    state = [rule.init(problem, model)]

    def step():
        state[0], _ = rule.step(state[0], model, y)

    return step


def step_ratios(problem, model, batch: int = 32, repeats: int = 5, seed: int = 0) -> dict:
    """Interleaved step timings (minimum over ``repeats``); ``model`` is copied, not trained."""
    y = torch.as_tensor(problem.sample(batch, seed)[1], dtype=torch.float32)
    t = interleaved({m: _stepper(m, problem, model, y) for m in ("adam", "sip", "hig")}, repeats)
    rows = batch * problem.operator.n_out
    n_params = sum(p.numel() for p in model.parameters() if p.requires_grad)
    return {"gd_step_s": t["adam"], "sip_step_s": t["sip"], "sip_vs_gd_step": t["sip"] / t["adam"],
            "hig_step_s": t["hig"], "gd_step_s_hig_net": t["adam"], "hig_jacobian": [rows, n_params],
            "hig_jacobian_mb": rows * n_params * 8 / 2**20, "step_batch": batch, "hig_batch": batch}
