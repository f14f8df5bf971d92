"""Bad and odd inputs of the thirteenth round (issue 48), and what round twelve left: `classical
--accept-bad` on a file whose y are 1e200 times its x (the linear MMSE's factors underflowed, the norms of
fields at 1e-200 too: "X contains NaN" and a NaN x-error on finite data)."""

from __future__ import annotations

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.training import references


def _one_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and "Warning" not in err and err.count("\n") == 1, err
    return err


SMALL_RUN = ["--steps", "2", "--n-train", "32", "--n-test", "8", "--prior-fit", "0", "--threads", "1", "-q"]


def test_classical_accept_bad_on_mismatched_units_reports_the_mismatch(tmp_path, capsys):
    p = pdeinv.load_problem("heat_1d", n=16)
    x, y = p.sample(200, 0)
    np.savez(tmp_path / "units.npz", x=x, y=y * 1e200)
    assert main(["classical", "heat_1d", "--set", "n=16", "--data", str(tmp_path / "units.npz"),
                 "--accept-bad"]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "Warning" not in err and "NaN" not in out + err, err
    assert "warning: the file's y differ from this problem's P x by 1" in err
    # the estimates are in y's units, 1e200 times the file's x: their error says so
    rows = {line.split(": ", 1)[0].split()[-1]: line.split(": ", 1)[1] for line in out.splitlines()}
    assert 1e199 < eval(rows["mmse_file_x"].replace("null", "None"))["x_err"] < 1e201


@pytest.mark.parametrize("a", [1e-150, 1.0, 1e150])  # a² σ² in float64
def test_the_linear_mmse_is_the_same_in_any_units(a):
    p = pdeinv.load_problem("heat_1d", n=16, noise=0.01)
    x, y = p.sample(300, 0)
    ref, info = references.mmse(p, x[:200])
    est, scaled = references.mmse(p, a * x[:200], a * a * info["sigma2"])
    np.testing.assert_allclose(est(a * y[200:]) / a, ref(y[200:]), rtol=1e-9, atol=1e-12)
    assert scaled["sigma2_rule"] == info["sigma2_rule"] == "noise"


@pytest.mark.parametrize("a", [1e-200, 1e200])
def test_the_noise_free_linear_mmse_of_fields_whose_squares_leave_float64(a):
    p = pdeinv.load_problem("heat_1d", n=16)
    x, y = p.sample(300, 0)
    ref, info = references.mmse(p, x[:200])
    est, scaled = references.mmse(p, a * x[:200])
    # σ = 1e-8 s_max: the solve amplifies rounding by up to 1e8, so the scaled factors agree to ~1e-8
    np.testing.assert_allclose(est(a * y[200:]) / a, ref(y[200:]), rtol=1e-6, atol=1e-8)
    assert scaled["sigma2_rule"] == info["sigma2_rule"] == "tiny σ = 1e-8·s_max"


@pytest.mark.parametrize("a", [1e-300, 1e300])
def test_the_l2_norm_of_fields_whose_squares_leave_float64(a):
    p = pdeinv.load_problem("heat_2d", n=8)
    x, _ = p.sample(4, 0)
    np.testing.assert_allclose(p.disc.norm(a * x) / a, p.disc.norm(x), rtol=1e-14)
    # an estimate 1e200 times the field: an error of 1e200, not NaN
    np.testing.assert_allclose(p.relative_error(1e100 * x, 1e-100 * x), 1e200, rtol=1e-12)
    assert np.array_equal(p.disc.norm(np.zeros((2, p.N))), [0.0, 0.0])


def test_a_prior_fit_says_how_long_it_will_take_after_its_first_steps(tmp_path, capsys):
    """The first held-out check comes after a pass over the draws (minutes at 64²): the pace comes
    after :data:`pdeinv.nets.refine.PACE_STEPS`."""
    from pdeinv.nets.refine import PACE_STEPS

    args = ["train", "heat_2d", "--set", "n=8", "--set", "noise=0.01", "--steps", "2", "--n-train", "64",
            "--n-test", "16", "--prior-fit", str(3 * PACE_STEPS), "--threads", "1"]
    assert main([*args, "--out", str(tmp_path / "r")]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "prior fit step" in ln]
    assert f"prior fit step {PACE_STEPS}/{3 * PACE_STEPS}: " in lines[1] and "left at this pace" in lines[1]
    assert main([*args, "-q", "--out", str(tmp_path / "q")]) == 0
    assert "prior fit" not in capsys.readouterr().err


def test_hig_names_the_route_it_falls_back_to_once_per_run():
    """The warning came once per step wherever a step's warnings filters were reset (the CLI showed
    it twice in a two-step run)."""
    import warnings

    import torch

    p = pdeinv.load_problem("heat_1d", n=16)
    torch.manual_seed(0)
    model = pdeinv.nets.mlp((64, 64))(p)
    rule = pdeinv.HIG(max_jacobian_gb=1e-4)  # the Gram route does not fit: a cheaper one is taken
    state = rule.init(p, model)
    _, y = p.sample(8, 0)
    y = torch.as_tensor(y, dtype=torch.float32)
    seen = []
    for _ in range(2):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rule.update(state, model, y)
        seen += [str(w.message) for w in caught if "taking the" in str(w.message)]
    assert len(seen) == 1 and "max_jacobian_gb=0.0001" in seen[0]


def test_a_thread_of_a_problem_module_that_raises_is_one_line(tmp_path, capsys):
    module = tmp_path / "threads.py"
    module.write_text("import threading\n"
                      "import pdeinv\n\n"
                      "def _bad():\n    raise RuntimeError('thread boom')\n\n"
                      "def make(**kw):\n"
                      "    t = threading.Thread(target=_bad, name='worker')\n    t.start()\n    t.join()\n"
                      "    return pdeinv.load_problem('heat_1d', n=8)\n")
    assert main(["train", str(module), *SMALL_RUN, "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    assert f"warning: thread 'worker' ended at {module}, line 5, in _bad: RuntimeError: thread boom" in err


@pytest.mark.parametrize("flag, argv", [
    ("--steps", ["train", "heat_1d", "--steps", "2", "--steps", "3", "--explain"]),
    ("--method", ["train", "heat_1d", "--method", "sip", "--method=adam", "--explain"]),
    ("--seed", ["train", "heat_1d", "--seed", "1", "--seed", "1", "--explain"]),
    ("--data", ["classical", "heat_1d", "--data", "a.npz", "--data", "b.npz"]),
    ("--level", ["predict", "run", "--data", "a.npz", "--out", "p.npz", "--level", "0.9", "--level", "0.5"]),
])
def test_a_flag_given_twice_is_refused(flag, argv, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    assert f"{flag} is given twice" in _one_error(capsys) and not list(tmp_path.iterdir())


def test_a_second_stress_into_the_same_folder_needs_overwrite(tmp_path, capsys):
    args = ["stress", "heat_1d", "--quick", "--set", "n=8", "--out", str(tmp_path / "s"), "-q"]
    assert main(args) == 0
    before = (tmp_path / "s" / "stress.json").read_bytes()
    capsys.readouterr()
    assert main(args) == 2
    assert "holds this command's earlier results (stress.json); pass --overwrite" in _one_error(capsys)
    assert (tmp_path / "s" / "stress.json").read_bytes() == before
    assert main([*args, "--overwrite"]) == 0


def test_bench_runs_on_nonlinear_physics(tmp_path, capsys):
    """It called the adjoint of a linear operator (AttributeError), then the linear references."""
    import json

    args = ["bench", "sine_gordon_1d", "--quick", "--set", "n=8", "--out", str(tmp_path / "b"), "-q"]
    assert main(args) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "error" not in err, err
    assert "reference: none (nonlinear physics)" in out
    record = json.loads((tmp_path / "b" / "bench.json").read_text())
    assert record["reference"] is None and record["ratios"]["adjoint_vs_forward"] > 0
    assert any("nonlinear physics" in note for note in record["notes"])
    assert record["methods"]["sip_cli_default"]["x_err"] < 1
