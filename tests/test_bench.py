"""The cost-ratio probe runs and returns finite ratios (no timing assertions: CI machines are noisy)."""

import numpy as np
from exact import load

from pdeinv.bench import operator_ratios


def test_operator_ratios_heat_and_wave():
    heat = operator_ratios(load("heat_2d", n=8), batch=4, repeats=1)
    for key in ("forward_vs_splu", "adjoint_vs_forward", "modal_speedup", "modal_agreement"):
        assert np.isfinite(heat[key]) and heat[key] > 0, key
    assert heat["modal_agreement"] < 1e-10
    wave = operator_ratios(load("wave_1d", n=8), batch=4, repeats=1)
    assert np.isfinite(wave["adjoint_vs_forward"]) and "modal_speedup" not in wave
