"""Stopping rules that never see x (pdeinv.training.stopping), through the common trainer."""

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.inverse import default_alpha, default_inverse
from pdeinv.methods import SIP, sgd
from pdeinv.training.checkpoint import Checkpoint
from pdeinv.training.stopping import DiscrepancyStop

STEPS = 1500


def _run(problem, stop, steps=STEPS, **kw):
    """A semi-convergent iteration: SIP with a noise-level Tikhonov inverse on minibatches of 32 and no
    target (``target=None``: the network fits the noisy y*), i.e. iterated Tikhonov, whose iterates
    approach the noise-fitting least-squares solution. (The CLI's default fits a denoised target
    instead, whose fixed point is regularized: nothing to stop there.)"""
    torch.manual_seed(0)
    inverse = default_inverse(problem.operator, alpha=default_alpha(problem.noise))
    rule = SIP(inverse=inverse, optimizer=sgd(1.0), normalize=True)
    return pdeinv.Trainer(problem, rule, steps=steps, seed=0, eval_every=10, progress=False,
                          batch_size=32, stop=stop, target=None, **{"prior": None, **kw}).fit()


@pytest.fixture(scope="module")
def noisy():
    return pdeinv.load_problem("heat_1d", noise=0.01)


@pytest.fixture(scope="module")
def stopped(noisy):
    return _run(noisy, DiscrepancyStop())


def test_discrepancy_stop_fires_where_the_residual_meets_the_noise(stopped):
    """The run ends at the first check with ρ ≤ τ; every earlier check had ρ > τ."""
    res = stopped
    assert res.metrics["stopped_by"] == "discrepancy"
    checks = [h["discrepancy"] for h in res.history if "discrepancy" in h]
    assert checks[-1] <= 1.1 < min(checks[:-1])
    assert res.metrics["steps"] < STEPS
    assert res.history[-1]["step"] == res.metrics["steps"] and "x_err" in res.history[-1]
    assert res.metrics["stop_rule"] == {"name": "discrepancy", "tau": 1.1, "noise": 0.01,
                                        "noise_source": "problem"}


def test_discrepancy_stop_beats_the_last_iterate(noisy, stopped):
    """Semi-convergence: the unstopped run ends worse than the stopped one (x only reported)."""
    full = _run(noisy, None)
    assert full.metrics["stopped_by"] == "steps" and full.metrics["steps"] == STEPS
    assert stopped.metrics["x_err"] < 0.9 * full.metrics["x_err"]
    best = min(h["x_err"] for h in full.history if "x_err" in h)
    assert stopped.metrics["x_err"] < 1.1 * best  # close to the oracle stopping step


def test_estimated_noise_level_stops_close_to_the_known_one(noisy, stopped):
    est = _run(noisy, DiscrepancyStop(noise="estimate"))
    info = est.metrics["stop_rule"]
    assert info["noise_source"] == "estimate" and abs(info["noise"] / 0.01 - 1) < 0.2
    assert est.metrics["stopped_by"] == "discrepancy"
    assert abs(est.metrics["steps"] - stopped.metrics["steps"]) <= 30
    assert est.metrics["x_err"] < 1.1 * stopped.metrics["x_err"]


def test_noise_free_problem_makes_the_rule_inert():
    p = pdeinv.load_problem("heat_1d", n=16, steps=10)
    res = _run(p, DiscrepancyStop(), steps=30)
    assert res.metrics["stopped_by"] == "steps" and res.metrics["steps"] == 30
    assert all(h["discrepancy"] == np.inf for h in res.history if "discrepancy" in h)


def test_a_stopped_run_stays_stopped_on_resume(noisy, tmp_path):
    ckpt = Checkpoint(tmp_path / "c.pt", every=50)
    first = _run(noisy, DiscrepancyStop(), checkpoint=ckpt)
    again = _run(noisy, DiscrepancyStop(), checkpoint=ckpt, resume=True)
    assert again.metrics["steps"] == first.metrics["steps"]
    assert again.metrics["stopped_by"] == "discrepancy"
    assert again.metrics["x_err"] == first.metrics["x_err"]


def test_callback_stop_is_reported():
    p = pdeinv.load_problem("heat_1d", n=16, steps=10)
    res = _run(p, None, steps=100, callbacks=[lambda rec, model: rec["step"] >= 7])
    assert res.metrics["stopped_by"] == "callback" and res.metrics["steps"] == 7


@pytest.mark.parametrize("kw, match", [(dict(tau=0), "tau"), (dict(noise=-1), "noise"),
                                       (dict(noise="guess"), "noise"), (dict(every=0), "every"),
                                       (dict(n_val=0), "n_val")])
def test_bad_settings_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        DiscrepancyStop(**kw)


def test_cli_defaults_on_noisy_data_fit_a_target_and_stop_only_without_one(tmp_path, capsys):
    """`pdeinv train heat_1d --set noise=0.01 --method sip` without flags: the denoised target (its fixed
    point is regularized: no stop needed, and none on by default); `--stop discrepancy` still stops;
    noise-free: neither."""
    import json

    from pdeinv.cli import main

    out = tmp_path / "run"
    assert main(["train", "--prior-fit", "0", "heat_1d", "--set", "noise=0.01", "--method", "sip",
                 "--out", str(out), "--export-samples", "0"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["stopped_by"] == "steps" and "stop_rule" not in m
    assert m["target"]["name"] == "spectral_wiener" and 0 < m["target"]["kept"] < m["target"]["modes"]
    assert m["x_err"] < 0.135  # best-α Tikhonov 0.127 on this test set (tests/test_accuracy.py)
    stopped = tmp_path / "stopped"
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--set", "noise=0.01", "--method", "sip", "--stop", "discrepancy",
                 "--out", str(stopped), "--export-samples", "0"]) == 0
    m = json.loads((stopped / "metrics.json").read_text())
    assert m["stopped_by"] == "discrepancy" and m["stop_rule"]["noise_source"] == "problem"
    assert "(discrepancy)" in capsys.readouterr().out
    quiet = tmp_path / "quiet"  # noise-free: no stopping rule unless asked for, only rounding to filter
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--method", "sip", "--steps", "20", "--out", str(quiet),
                 "--export-samples", "0"]) == 0
    m = json.loads((quiet / "metrics.json").read_text())
    assert m["stopped_by"] == "steps" and "stop_rule" not in m and m["target"]["name"] == "tikhonov_rounding"


def test_cli_refuses_an_optimizer_for_a_rule_without_one(tmp_path, capsys):
    from pdeinv.cli import main

    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--method", "adam", "--optimizer", "sgd", "--steps", "2",
                 "--out", str(tmp_path / "o")]) == 2
    assert "optimizer (--optimizer) does not apply to method 'adam'" in capsys.readouterr().err
    assert not (tmp_path / "o" / "metrics.json").exists()


class _Fixed(torch.nn.Module):
    """x̂ = s·y₀-like output: a scalar times a fixed field, the scalar set from outside."""

    def __init__(self, x):
        super().__init__()
        self.s = torch.nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.register_buffer("x", torch.as_tensor(x))

    def forward(self, y):
        return self.s * self.x[: y.shape[0]]


def test_plateau_stop_fires_after_patience_checks_without_a_gain():
    """The held-out residual is checked at each call: it fires at the ``patience``-th check in a row whose
    residual is not below ``(1 − min_gain)`` of the best, and a gain resets the count."""
    from pdeinv.training.stopping import PlateauStop

    p = pdeinv.load_problem("heat_1d", n=16, steps=10)
    x, y = p.sample(8, 0)
    rule, model = PlateauStop(patience=2, min_gain=0.01), _Fixed(x)
    state = rule.init(p, y, y)
    fired = []
    for s in (0.0, 0.5, 0.9, 0.9, 0.95, 0.999, 0.999, 0.999):  # the residual falls by (1 − s)²
        model.s.data.fill_(s)
        state, info, stop = rule.check(state, model)
        fired.append(stop)
        assert info["plateau"] >= state.best
    # 0.9 → 0.9: no gain (1st); 0.95 gains; 0.999 gains; then two without: fires at the second
    assert fired == [False, False, False, False, False, False, False, True]
    with pytest.raises(ValueError, match="patience"):
        PlateauStop(patience=0)


def test_plateau_stop_puts_the_network_back_to_its_lowest_residual():
    """When the held-out residual rises after its lowest point (SIP on sine_gordon_2d at 16 k unknowns),
    the rule fires with the parameters of that point restored; checks before it keep no stale copy."""
    from pdeinv.training.stopping import PlateauStop

    p = pdeinv.load_problem("heat_1d", n=16, steps=10)
    x, y = p.sample(8, 0)
    rule, model = PlateauStop(patience=2, min_gain=0.01), _Fixed(x)
    state = rule.init(p, y, y)
    for s in (0.0, 0.9, 0.5, 0.3):  # the best at 0.9, then two checks worse
        model.s.data.fill_(s)
        state, _, stop = rule.check(state, model)
    assert stop and float(model.s.detach()) == 0.9
    assert float(state.kept["s"]) == 0.9 and state.kept["s"].data_ptr() != model.s.data_ptr()


def test_auto_stops_nonlinear_runs_on_the_plateau_in_python_as_in_the_cli():
    """`--stop auto` and Python's default `stop="auto"` (one chooser): nonlinear physics gets the plateau
    stop, checked ~30 times a run; linear noise-free runs none; a Trainer given no stop stops a nonlinear
    run on the plateau as `pdeinv train` does (it ran all its steps before)."""
    from pdeinv.training.arguments import stop
    from pdeinv.training.stopping import PlateauStop, chosen

    ac = pdeinv.load_problem("allen_cahn_1d", n=16, steps=10)
    assert chosen(ac, 30) == PlateauStop(every=1) and chosen(ac, 1000).every == 33
    assert stop("plateau", ac, 1000) == chosen(ac, 1000)  # by name, as --stop plateau
    assert chosen(pdeinv.load_problem("heat_1d", n=16), 30) is None
    # noisy data: none where a denoised target fits, in the basis of P D with the network's decoder too
    wave = pdeinv.load_problem("wave_2d", n=12, noise=0.01, backend="steps")  # no spectral basis of its own
    assert chosen(wave, 30).name == "discrepancy"
    assert chosen(wave, 30, pdeinv.nets.reduced(k_in=8, k_out=16, k_max=16)(wave)) is None
    res = pdeinv.Trainer(ac, "sip", steps=30, n_train=64, n_test=8, seed=0, progress=False,
                         prior=None, calibration=None).fit()
    assert res.metrics["stopped_by"] == "plateau" and res.metrics["steps"] < 30
    assert pdeinv.Trainer(ac, "sip", stop=None, prior=None, calibration=None).stop is None


def test_a_step_that_moves_nothing_ends_the_run_and_changes_no_result(monkeypatch):
    """``converged``: a step that moved no parameter by more than STILL of the largest, at a rounding-level
    loss; STILL_STEPS of them in a row end the run. SIP on a noisy wave reaches its fixed point in a few
    steps and stops there with the 30-step run's x-error; a noise-free heat run, whose weak modes keep
    improving x at a rounding-level loss, runs all its steps."""
    from pdeinv.methods.presets import make_rule
    from pdeinv.training import stopping

    a = torch.tensor([1.0, -2.0, 3.0], dtype=torch.float64)
    assert stopping.converged(a, a.clone(), 0.0, 1.0, 10)
    assert stopping.converged(a, a + 1e-12, 1e-30, 1.0, 10)
    assert not stopping.converged(a, a + 1e-8, 0.0, 1.0, 10)
    assert not stopping.converged(a[:0], a[:0], 0.0, 1.0, 10)
    assert not stopping.converged(a, a.clone(), 1e-20, 1.0, 10)  # still, but the loss is not at rounding
    runs, STILL = {}, stopping.STILL
    for still in (STILL, 0.0):
        monkeypatch.setattr(stopping, "STILL", still)
        for name, kw in (("wave_2d", {"n": 12, "noise": 0.01}), ("heat_1d", {"n": 32})):
            p = pdeinv.load_problem(name, **kw)
            rule, _ = make_rule("sip", p, p.noise)
            runs[name, still] = pdeinv.train(p, rule, progress=False, prior=None).metrics
    wave, wave_all = runs["wave_2d", STILL], runs["wave_2d", 0.0]
    assert wave["stopped_by"] == "converged" and wave["steps"] <= 6 and wave_all["steps"] == 30
    assert wave["x_err"] == pytest.approx(wave_all["x_err"], rel=1e-9)
    assert runs["heat_1d", STILL]["steps"] == 30
    assert runs["heat_1d", STILL]["x_err"] == runs["heat_1d", 0.0]["x_err"]
