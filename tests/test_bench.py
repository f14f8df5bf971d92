"""Benchmark smoke tests: every contract key present and finite (or a documented null); bad input.

No timing assertions: CI machines are noisy.
"""

import json
import math

import numpy as np
import pytest
from exact import load

import pdeinv
from pdeinv.bench import bench, operator_ratios
from pdeinv.bench.forward import pareto
from pdeinv.cli import main

RATIOS = ("forward_vs_splu", "adjoint_vs_forward", "modal_speedup", "sip_vs_gd_step", "hig_step_s")
METHODS = ("sip_cli_default", "hig_cli_default", "adam", "sgd", "sip", "hig", "gauss_newton",
           "sip_whitened_mlp")
TINY = ["--set", "n=8", "--set", "steps=10"]


def test_operator_ratios_heat_and_wave():
    heat = operator_ratios(load("heat_2d", n=8), batch=4, repeats=1)
    for key in ("forward_vs_splu", "adjoint_vs_forward", "modal_speedup", "modal_agreement"):
        assert np.isfinite(heat[key]) and heat[key] > 0, key
    assert heat["modal_agreement"] < 1e-10
    wave = operator_ratios(load("wave_1d", n=8), batch=4, repeats=1)
    assert np.isfinite(wave["adjoint_vs_forward"]) and "modal_speedup" not in wave


def _finite(v):
    return isinstance(v, (int, float)) and math.isfinite(v)


def check_contract(res: dict, nulls=()):
    for key in RATIOS:
        assert key in res["ratios"], key
        v = res["ratios"][key]
        assert (v is None and key in nulls) or (_finite(v) and v > 0), (key, v)
    for name in METHODS:
        for key in ("x_err", "y_err", "wall_s"):
            assert _finite(res["methods"][name][key]), (name, key)
    for key in ("mmse_x_err", "tikhonov_best_x_err"):
        assert _finite(res["reference"][key]), key
    for key in ("cores", "torch", "scipy", "numpy", "platform"):
        assert res["machine"][key], key
    assert res["skips"] and all(isinstance(v, dict) for v in res["skips"].values())
    rows = res["amortization"]["rows"]
    assert "network" in rows and len(rows) >= 2  # the network and at least one classical solve
    for name, row in rows.items():
        assert _finite(row["s_per_sample"]) and _finite(row["x_err"]), name
        gain = row["s_per_sample"] - rows["network"]["s_per_sample"]
        train_s = res["amortization"]["train_s"]
        expected = None if name == "network" or gain <= 0 else math.ceil(train_s / gain)
        assert row["break_even_samples"] == expected, name


def test_bench_cli_quick_heat(tmp_path):
    assert main(["bench", "heat_2d", "--quick", *TINY, "--budget-s", "0.2", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "bench.json").read_text())
    check_contract(res)
    assert (tmp_path / "forward.png").stat().st_size > 0 and (tmp_path / "methods.png").stat().st_size > 0
    assert res["skips"]["no_adjoint_under_no_grad"]["adjoint_calls_under_no_grad"] == 0
    assert res["skips"]["no_trajectory"]["saved"] > 1  # the stored trajectory takes more memory
    ok = [p for p in res["forward"]["points"] if p["outcome"] == "ok"]
    assert {p["backend"] for p in ok} >= {"BE steps", "CN steps"}  # modal: refused on so few unknowns
    assert all(p["message"] for p in res["forward"]["points"] if p["outcome"] == "refused")
    assert all(p["error"] < 0.05 for p in ok)  # n = 8 already gets the mode to a few percent
    assert "tikhonov_cg" in res["amortization"]["rows"]
    # the heat default network is the prior decoder (heat is not reversible): the whitened linear map is
    # an alternative to it and is benched
    assert "sip_whitened_linear" in res["methods"] and "sip_mlp_standardized" in res["methods"]


def test_bench_api_quick_wave(tmp_path):
    res = bench(pdeinv.load_problem("wave_1d", n=8, steps=10), tmp_path, quick=True, budget_s=0.2,
                log=lambda *_: None)
    check_contract(res, nulls=("modal_speedup",))
    assert any("modal_speedup" in note for note in res["notes"])
    assert json.loads((tmp_path / "bench.json").read_text())["ratios"]["modal_speedup"] is None
    assert "time_reversal" in res["amortization"]["rows"]  # chosen because the Wave offers reverse


def test_pareto_front():
    pts = [{"outcome": "ok", "time_s": t, "error": e} for t, e in ((1, 1), (2, 0.5), (3, 0.7), (0.5, 2))]
    pts.append({"outcome": "refused"})
    assert sorted(pareto(pts)) == [0, 1, 3]


@pytest.mark.parametrize("argv, words", [
    (["bench", "no_such_problem", "--out", "{d}/o"], "unknown problem"),
    (["bench", "heat_2d", "--budget-s", "0", "--out", "{d}/o"], "--budget-s"),
    (["bench", "heat_2d", "--budget-s", "-3", "--out", "{d}/o"], "--budget-s"),
    (["bench", "heat_2d", "--out", "{d}/file"], "is a file"),
    (["bench", "heat_2d", "--set", "kappa=-1", "--out", "{d}/o"], "kappa"),
])
def test_bench_bad_input(tmp_path, capsys, argv, words):
    (tmp_path / "file").write_text("x")
    assert main([a.format(d=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err


def test_backend_lines_of_a_scene_that_steps_through_time():
    """``pdeinv bench wave_2d --set backend=steps`` ended in an AttributeError (the scene's operator
    has no compiled backend); every line now agrees with stepping."""
    from pdeinv.bench.backends import lines

    res = lines(pdeinv.load_problem("wave_1d", n=8, steps=10, backend="steps"), batch=4, repeats=1)
    assert set(res["lines"]) == {"steps", "dense", "svd"}
    assert all(line["outcome"] == "ok" and line["agreement"] < 1e-12 for line in res["lines"].values())


def test_the_stepping_line_of_a_compiled_scene_steps():
    """bench's "steps" figures of a compiled scene (wave_2d: a dense map) once timed the dense map and
    compared it with itself (agreement 0); stepping() now rebuilds the time stepping."""
    from pdeinv.bench.timing import stepping

    op = pdeinv.load_problem("wave_2d", n=8).operator
    assert op.backend is not None
    run = stepping(op)
    assert run is not op and run.backend is None
    X = np.random.default_rng(0).standard_normal((3, op.n_in))
    diff = np.linalg.norm(run.forward(X) - op.forward(X)) / np.linalg.norm(op.forward(X))
    assert 0 < diff < 1e-12  # the same map, by another computation


def test_the_forward_ladder_of_a_3d_scene_refines_in_3d():
    """heat_3d's ladder ran on interval meshes (~22 % error that did not fall); on unit cubes the
    spatial error falls at second order: n 4 → 8 divides it by ~4 (CN, 100 steps: 0.079 → 0.020)."""
    from pdeinv.bench.forward import ladder

    res = ladder(pdeinv.load_problem("heat_3d", n=8), [4, 8], [100], repeats=1, batch=2)
    ok = [pt for pt in res["points"] if pt["outcome"] == "ok"]
    cn = {pt["n"]: pt["error"] for pt in ok if pt["backend"].startswith("CN")}
    assert cn[8] < 0.03 and 3.0 < cn[4] / cn[8] < 5.0


def test_a_compiled_scene_is_benched_against_its_time_stepping():
    """wave_2d (a dense map): the dense line agrees with stepping to rounding but not exactly (it is
    no longer compared with itself), the scene keeps its own backend, and the ratios and the
    factorization skip time the Newmark stepping."""
    from pdeinv.bench import skips
    from pdeinv.bench.backends import lines

    p = pdeinv.load_problem("wave_2d", n=8)
    assert p.operator.kind == "dense"
    res = lines(p, batch=4, repeats=1)["lines"]
    assert res["steps"]["agreement"] == 0 and 0 < res["dense"]["agreement"] < 1e-12
    assert p.operator.kind == "dense"
    ratios = operator_ratios(p, batch=4, repeats=1)
    assert ratios["solver"] and ratios["forward_vs_splu"] > 0 and "modal_speedup" not in ratios
    assert "θ-scheme" in ratios["modal_refused"]
    reuse = skips.factorization(p.operator, np.ones((2, p.N)), 1)
    assert reuse["saved"] > 1 and "skipped" not in reuse


def test_the_forward_ladder_runs_the_scene_itself():
    """The reaction of reaction_diffusion_2d is part of the exact mode (r = 5 damps it by e⁻⁵ more);
    scenes without an exact mode (sensors, advection) are skipped with the reason."""
    from pdeinv.bench.forward import exact_factor, ladder

    p = pdeinv.load_problem("reaction_diffusion_2d", n=8, reaction=5.0)
    assert exact_factor(p) == pytest.approx(np.exp(-(0.01 * 2 * np.pi**2 + 5.0)))
    ok = [pt for pt in ladder(p, [8], [100, 1000], repeats=1, batch=2)["points"] if pt["outcome"] == "ok"]
    assert {pt["backend"] for pt in ok} >= {"BE steps", "CN steps"}
    # second order in time (CN), or BE's first-order error O(n (dt μ)²) ≈ 0.13 at 100 steps down 10x
    assert all(pt["error"] < 0.02 for pt in ok if pt["backend"].startswith("CN") or pt["steps"] == 1000)
    for name in ("heat_sensors_2d", "advection_diffusion_2d"):
        res = ladder(pdeinv.load_problem(name, n=4, steps=10), [4], [10], repeats=1)
        assert res["points"] == [] and "no exact mode" in res["skipped"], name


def test_the_method_candidates_are_the_presets():
    """Every row of the methods table is a preset of ``pdeinv train --method`` (rule, batch, network),
    its knob scaled; HIG trains the default network (the Kronecker route)."""
    from pdeinv.bench.methods import CANDIDATES, compare, setup
    from pdeinv.methods.presets import hyperparameters

    p = pdeinv.load_problem("heat_1d", n=8, steps=10)
    for name, cand in CANDIDATES.items():
        rule, hp, _ = setup(p, cand)
        assert hp == hyperparameters(cand.method, p, p.noise, **cand.fixed), name
        assert setup(p, cand, 3.0)[1][cand.knob] == pytest.approx(3.0 * hp[cand.knob]), name
    assert setup(p, CANDIDATES["gauss_newton"])[0].exponent == -1.0
    res = compare(p, 0.3, n_train=16, n_test=8, eval_every=1, sweep=False,
                  candidates={"hig": CANDIDATES["hig"]})["hig"]
    assert res["network"] == "problem.model()" and res["preset"] == "hig" and _finite(res["x_err"])


def test_the_bench_uses_the_public_physics_api():
    """No class checks on physics types, no private reach-ins, no operators rebuilt by hand and no
    rule registry of its own (issue 24): the bench asks capabilities, ``stepping()`` and the presets."""
    import pathlib
    import re

    import pdeinv.bench

    banned = [r"isinstance\([^)]*\b(Heat|Wave|Leapfrog|Propagator|Theta|Newmark)\b",
              r"\btype\([^)]*\) (not )?in",
              r"\._forward\b|\._adjoint\b|\.lu\s*=[^=]", r"\b(Heat|Wave|Leapfrog|Propagator|Theta)\(",
              r"\b(GD|SIP|HIG)\(", r"heat_backends|from \.\.physics import"]
    for path in pathlib.Path(pdeinv.bench.__file__).parent.glob("*.py"):
        text = path.read_text()
        if path.name == "cases.py":  # the stress sweeps train hand-made rules on purpose (τ, η sweeps)
            text = re.sub(r"\b(GD|SIP|HIG)\(", "rule(", text)
        for pattern in banned:
            assert not re.search(pattern, text), (path.name, pattern)
