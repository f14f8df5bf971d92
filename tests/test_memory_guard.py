"""The memory guard counts what a run builds (issue 35): each estimate against what is allocated."""

import tracemalloc

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv import nets
from pdeinv.inverse import TikhonovCG
from pdeinv.training import plan as budget
from pdeinv.util import memory


def _bytes(model) -> tuple[int, int]:
    params = sum(p.numel() * p.element_size() for p in model.parameters())
    buffers = sum(b.numel() * b.element_size() for b in model.buffers())
    return params, buffers


@pytest.mark.parametrize("kind", ["whitened", "reduced", "linear", "default"])
def test_the_network_estimate_is_within_a_factor_of_the_built_network(kind, monkeypatch):
    """``network_size`` for each ``--net`` against the parameters and buffers of the network built:
    an upper bound (the decoder may keep fewer columns), never more than 3x off."""
    monkeypatch.setattr(nets, "REDUCED_ABOVE", 100)  # heat_2d n=16 (225 unknowns): the reduced net
    p = pdeinv.load_problem("heat_2d", n=16)
    size = nets.network_size(p, kind)
    torch.manual_seed(0)
    model = pdeinv.io.runs.network(p, {"kind": kind})
    params, buffers = _bytes(model)
    copies = budget.STATE_COPIES["adam"]  # value, gradient, two Adam moments; the buffers
    built = copies * params + buffers
    est = copies * size["dtype_bytes"] * size["params"] + size["dtype_bytes"] * size["buffers"]
    assert built <= est <= 3 * built, (kind, built, est)


def test_the_mlp_estimate_is_its_parameter_count():
    p = pdeinv.load_problem("heat_2d", n=8)
    size = nets.network_size(p, hidden=(32, 16))
    model = pdeinv.io.runs.network(p, {"kind": "mlp", "hidden": [32, 16]})
    assert size["params"] == sum(q.numel() for q in model.parameters())


def test_the_cg_inverse_estimate_is_within_a_factor_of_tracemalloc():
    """``TikhonovCG.memory_bytes(B)`` against the peak numpy allocation of one solve of ``B`` rows
    (its arrays and the reorthogonalization history), on a stepping heat operator."""
    p = pdeinv.load_problem("heat_2d", n=24, backend="steps", steps=10)
    inv = TikhonovCG(p.operator, p.disc.M, alpha=1e-6, rtol=1e-8, maxiter=30)
    x, y = p.sample(16, seed=1)
    x0 = np.zeros_like(x)
    tracemalloc.start()
    inv(y, x0)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    est = inv.memory_bytes(16)
    assert peak / 3 <= est <= 3 * peak, (peak, est)


def test_the_reorthogonalization_history_is_bounded_and_the_solve_still_converges():
    """With a tiny ``reorth_gb`` only the last two iterations are kept (local reorthogonalization):
    the same solution to the tolerance, memory O(B·N) whatever the iteration count."""
    p = pdeinv.load_problem("heat_2d", n=16, backend="steps", steps=10)
    x, y = p.sample(4, seed=2)
    full = TikhonovCG(p.operator, p.disc.M, alpha=1e-6, rtol=1e-10)
    small = TikhonovCG(p.operator, p.disc.M, alpha=1e-6, rtol=1e-10, reorth_gb=1e-9)
    assert small.history_length(4) == 2 and full.history_length(4) > 1000
    a, b = full(y, np.zeros_like(x)), small(y, np.zeros_like(x))
    assert small.last_info["converged"]
    # rtol bounds the normal equations' residual; the solution's error is up to 1/α times that
    assert np.linalg.norm(a - b) / np.linalg.norm(a) <= 1e-4


def test_the_guard_refuses_the_full_whitened_map_at_65k_unknowns_in_one_line():
    """``--net whitened`` at 65 025 unknowns is an N × N map (68 GB in float64): refused before anything
    is built, naming the estimate, its largest part and the budget in one line; the default network of
    the same run fits in 16 GB."""
    class Op:
        n_in = n_out = 65_025

    class Big:  # what the guard reads of a problem: its sizes, name, inverse and N
        name, operator, N, model_factory, inverse_simulator = "heat_2d", Op(), 65_025, None, None
        points = np.zeros((2, 65_025))
        disc = None

    memory.set_budget(16.0)
    try:
        with pytest.raises(memory.MemoryBudgetError) as err:
            budget.check_training(Big(), 1024, 128, 1024, net="whitened", method="sip")
        text = str(err.value)
        assert "\n" not in text and "network" in text and "budget of 16 GB" in text
        parts = budget.check_training(Big(), 1024, 128, 1024, net="reduced", method="sip")
        assert sum(parts.values()) < 16e9
    finally:
        memory.set_budget(None)
