"""Own data: ``Trainer(data=...)`` (array, tensor, Dataset), ``pdeinv train --data`` with its held-out
rows, ``pdeinv predict`` and ``pdeinv.load_run``; bad files refused with exit 2 and one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from stderr import said

import pdeinv
from pdeinv.cli import main
from pdeinv.methods import GD, adam
from pdeinv.nets import Net
from pdeinv.nets.refine import Refined
from pdeinv.training.stopping import DiscrepancyStop
from pdeinv.training.trainer import Trainer

pytestmark = pytest.mark.usefixtures("one_thread")  # small dense work: one torch thread


@pytest.fixture(scope="module")
def heat():
    return pdeinv.load_problem("heat_1d", n=16, backend="modal")


@pytest.fixture(scope="module")
def pairs(heat):
    return heat.sample(60, seed=3)


def fit(heat, data, **kw):
    kw = {"steps": 3, "n_test": 10, "batch_size": 8, "progress": False, **kw}
    return Trainer(heat, GD(adam(1e-3)), data=data, **{"prior": None, **kw})


@pytest.mark.parametrize("wrap", [np.asarray, torch.tensor, lambda y: torch.utils.data.TensorDataset(
    torch.tensor(y))], ids=["numpy", "tensor", "dataset"])
def test_trainer_trains_on_own_observations_and_holds_out_the_last_rows(heat, pairs, wrap):
    x, y = pairs
    t = fit(heat, wrap(y), data_x=x)
    r = t.fit()
    assert t.n_train == 50 and r.metrics["data"]["rows"]["test"] == [50, 60]
    np.testing.assert_array_equal(t.held_out()[1], y[50:])
    np.testing.assert_array_equal(t._data()[0], y[:50])
    # the whitening / input scaling is fitted on the training rows only
    net = r.model.base if isinstance(r.model, Refined) else r.model
    np.testing.assert_allclose(net.pre.mean.numpy() if isinstance(net, Net) else net.shift.numpy(),
                               y[:50].mean(0), rtol=1e-5, atol=1e-7)
    assert 0 < r.metrics["x_err"] < 2


def test_without_x_only_the_y_error_is_reported_and_the_stop_rows_come_from_the_data(heat, pairs):
    _, y = pairs
    t = fit(heat, y, stop=DiscrepancyStop(n_val=5, noise="estimate"))
    r = t.fit()
    assert r.metrics["x_err"] is None and r.metrics["y_err"] > 0
    assert r.metrics["data"]["rows"] == {"train": [0, 45], "stop": [45, 50], "test": [50, 60]}


@pytest.mark.parametrize("data, match", [
    (np.zeros((60, 3)), r"data has shape \(60, 3\); expected \(B, 15\)"),
    (np.zeros(15), r"data has shape \(15,\)"),
    (np.zeros((0, 15)), "no rows"),
    (np.full((60, 15), np.nan), "NaN/Inf"),
    (np.array([["a"] * 15] * 20), "dtype"),
    (np.arange(165.0).reshape(11, 15), "fewer than 2 to train on"),
    (np.ones((11, 15)), "all 11 rows are the same observation"),
])
def test_trainer_refuses_bad_own_data(heat, data, match):
    with pytest.raises(ValueError, match=match):
        fit(heat, data)


def test_a_checkpoint_of_other_data_is_not_resumed(heat, pairs, tmp_path):
    _, y = pairs
    ckpt = pdeinv.Checkpoint(tmp_path / "c.pt", every=1)
    fit(heat, y, checkpoint=ckpt).fit()
    with pytest.raises(ValueError, match="data"):
        fit(heat, y[::-1].copy(), checkpoint=ckpt, resume=True, steps=5).fit()


# -- the command line ----------------------------------------------------------------------------

SMALL = ["--set", "n=16", "--set", "backend=modal", "--n-test", "10", "--batch-size", "8", "--steps", "3",
         "--export-samples", "2", "--accept-bad"]  # 3 steps of 8 rows: y_err ~1 (pdeinv.training.verdict)


def test_cli_train_predict_and_load_run(heat, pairs, tmp_path, capsys):
    x, y = pairs
    np.savez(tmp_path / "train.npz", y=y[:50], x=x[:50])
    np.savez(tmp_path / "obs.npz", y=y[50:], x=x[50:])
    out = tmp_path / "run"
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--data", str(tmp_path / "train.npz"), *SMALL, "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["data"]["file"].endswith("train.npz") and m["data"]["rows"]["test"] == [40, 50]
    assert m["n_train"] == 40 and m["x_err"] is not None
    problem, model = pdeinv.load_run(out)
    assert problem.settings == heat.settings
    pred = tmp_path / "pred.npz"
    assert main(["predict", str(out), "--data", str(tmp_path / "obs.npz"), "--out", str(pred),
                 "--vtu", str(tmp_path / "pred.vtu")]) == 0
    assert "x_err" in capsys.readouterr().out
    xhat = np.load(pred)["x"]
    np.testing.assert_allclose(xhat, pdeinv.io.export.predict(model, y[50:]))
    from pdeinv.io.export import read_fields

    assert read_fields(tmp_path / "pred.vtu")[2]["x_pred"].shape[0] == 10


def _bad_files(tmp, heat):
    y = heat.sample(30, seed=0)[1]
    files = {"wrong_m.npz": dict(y=np.zeros((30, 7))), "nan.npz": dict(y=np.where(y > 0, np.nan, y)),
             "no_y.npz": dict(obs=y), "bad_x.npz": dict(y=y, x=np.zeros((30, 4))),
             "x_rows.npz": dict(y=y, x=np.zeros((29, 15))), "empty_y.npz": dict(y=np.zeros((0, 15)))}
    for name, arrays in files.items():
        np.savez(tmp / name, **arrays)
    (tmp / "empty.npz").write_bytes(b"")
    (tmp / "text.npz").write_text("y = 1, 2, 3\n")
    np.save(tmp / "single.npy", y)


@pytest.mark.parametrize("command, file, match", [
    ("train", "wrong_m.npz", r"y has shape \(30, 7\); expected \(B, 15\)"),
    ("train", "nan.npz", "NaN/Inf"),
    ("train", "no_y.npz", "has no array 'y'"),
    ("train", "bad_x.npz", r"x has shape \(30, 4\); expected \(B, 15\)"),
    ("train", "x_rows.npz", "x has 29 rows but y has 30"),
    ("train", "empty_y.npz", "no rows"),
    ("train", "empty.npz", "is empty"),
    ("train", "text.npz", "is not an .npz archive"),
    ("train", "single.npy", "is not an .npz archive"),
    ("train", "missing.npz", "does not exist"),
    ("predict", "wrong_m.npz", r"y has shape \(30, 7\)"),
    ("predict", "nan.npz", "NaN/Inf"),
    ("predict", "no_y.npz", "has no array 'y'"),
    ("predict", "empty.npz", "is empty"),
])
def test_cli_bad_data_files_exit_2_with_one_line(heat, tmp_path, capsys, command, file, match):
    _bad_files(tmp_path, heat)
    run = tmp_path / "run"
    if command == "predict":
        x, y = heat.sample(30, seed=1)
        np.savez(tmp_path / "ok.npz", y=y)
        assert main(["train", "--prior-fit", "0",
                     "heat_1d", "--data", str(tmp_path / "ok.npz"), *SMALL, "--out", str(run)]) == 0
        capsys.readouterr()
        argv = ["predict", str(run), "--data", str(tmp_path / file), "--out", str(tmp_path / "p.npz")]
    else:
        argv = ["train", "--prior-fit", "0",
                "heat_1d", "--data", str(tmp_path / file), *SMALL, "--out", str(run)]
    code = main(argv)
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"pdeinv {command}: error: ") and "Traceback" not in err[0]
    import re

    assert re.search(match, err[0]), err[0]
    assert not (tmp_path / "p.npz").exists()


@pytest.mark.parametrize("setup, argv_tail, match", [
    ("none", [], "is not a directory"),
    ("empty", [], "holds no run.json or model.pt"),
    ("no_model", [], "holds no model.pt"),
    ("ok", ["--out-name", "p.txt"], "ending in .npz"),
    ("ok", ["--vtu", "p.png"], "ending in .vtu or .xdmf"),
])
def test_cli_predict_refuses_a_run_folder_without_a_model(heat, pairs, tmp_path, capsys, setup, argv_tail,
                                                         match):
    run = tmp_path / "run"
    x, y = pairs
    np.savez(tmp_path / "obs.npz", y=y)
    if setup != "none":
        run.mkdir()
    if setup in ("no_model", "ok"):
        assert main(["train", "--prior-fit", "0",
                     "heat_1d", "--data", str(tmp_path / "obs.npz"), *SMALL, "--out", str(run)]) == 0
        capsys.readouterr()
    if setup == "no_model":
        (run / "model.pt").unlink()
    out = "p.npz"
    if argv_tail[:1] == ["--out-name"]:
        out, argv_tail = argv_tail[1], []
    code = main(["predict", str(run), "--data", str(tmp_path / "obs.npz"), "--out", str(tmp_path / out),
                 *argv_tail])
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("pdeinv predict: error: ") and match in err[0]


def test_cli_n_train_with_data_is_refused(tmp_path, pairs, capsys):
    np.savez(tmp_path / "d.npz", y=pairs[1])
    code = main(["train", "--prior-fit", "0",
                 "heat_1d", "--data", str(tmp_path / "d.npz"), "--n-train", "20", *SMALL,
                 "--out", str(tmp_path / "run")])
    assert code == 2 and "--n-train does not apply with --data" in capsys.readouterr().err


@pytest.mark.parametrize("out, vtu, match", [
    ("obs.npz", None, "--out 'OBS' is the same file as --data"),
    ("p.npz", "run/model.pt", "is the same file as the run's model"),
    ("p.npz", "p.npz", "--vtu 'P' is the same file as --out"),
])
def test_cli_predict_never_writes_over_an_input(tmp_path, pairs, capsys, out, vtu, match):
    """``predict RUN --data F.npz --out F.npz`` once overwrote the user's observations (exit 0)."""
    x, y = pairs
    np.savez(tmp_path / "obs.npz", y=y)
    assert main(["train", "--prior-fit", "0", "heat_1d", "--data", str(tmp_path / "obs.npz"), *SMALL,
                 "--out", str(tmp_path / "run")]) == 0
    capsys.readouterr()
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    argv = ["predict", str(tmp_path / "run"), "--data", str(tmp_path / "obs.npz"),
            "--out", str(tmp_path / out)]
    argv += ["--vtu", str(tmp_path / vtu)] if vtu else []
    code = main(argv)
    err = capsys.readouterr().err.splitlines()
    match = match.replace("OBS", str(tmp_path / "obs.npz")).replace("'P'", repr(str(tmp_path / "p.npz")))
    assert code == 2 and len(err) == 1 and match in err[0], err
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_data_from_another_discretization_is_measured_and_warned_about(heat, tmp_path, capsys):
    """The same scene with 10 instead of 100 backward-Euler steps: a model mismatch well above rounding,
    recorded in metrics.json and said on stderr with both numbers, and a run fitting it exactly (noise
    level 0) ends worse than predicting zero: exit 3 (pdeinv.training.verdict); our own data: rounding, no
    warning, exit 0."""
    from pdeinv.training.data import model_mismatch

    other = pdeinv.load_problem("heat_1d", n=16, steps=10)
    x, y = other.sample(60, seed=3)
    ours = pdeinv.load_problem("heat_1d", n=16, backend="steps")
    own_x, own_y = ours.sample(60, seed=3)
    assert model_mismatch(ours.operator, own_x, own_y) < 1e-12
    mismatch = model_mismatch(ours.operator, x, y)
    assert mismatch > 1e-3
    np.savez(tmp_path / "other.npz", y=y, x=x)
    np.savez(tmp_path / "own.npz", y=own_y, x=own_x)
    tail = ["--set", "n=16", "--set", "backend=steps", "--n-test", "10", "--batch-size", "8", "--steps", "2",
            "--export-samples", "0"]
    assert main(["train", "--prior-fit", "0", "heat_1d", "--data", str(tmp_path / "other.npz"), *tail,
                 "--out", str(tmp_path / "a")]) == 3
    err = capsys.readouterr().err
    assert f"differ from this problem's P x by {mismatch:.3g}" in err and "noise level 0 explains" in err
    assert json.loads((tmp_path / "a" / "metrics.json").read_text())["data"]["model_mismatch"] == \
        pytest.approx(mismatch)
    assert main(["train", "--prior-fit", "0", "heat_1d", "--data", str(tmp_path / "own.npz"), *tail,
                 "--out", str(tmp_path / "b")]) == 0
    assert "differ from this problem" not in capsys.readouterr().err
    # noisy data of our own simulator at its declared level: explained
    noisy = pdeinv.load_problem("heat_1d", n=16, backend="steps", noise=0.05)
    nx, ny = noisy.sample(60, seed=4)
    assert 0.04 < model_mismatch(noisy.operator, nx, ny) < 1.1 * 0.05


def test_a_float32_file_trains_at_its_rounding_level(tmp_path, capsys):
    """float32 rounding is noise of relative level 6e-8: declared with a warning, recorded in run.json
    (SIP from the same file assumed exact data: x-error 17.7 against 0.02 in float64)."""
    p = pdeinv.load_problem("heat_1d", n=16)
    x, y = p.sample(300, 1)
    np.savez(tmp_path / "f32.npz", y=y.astype(np.float32), x=x.astype(np.float32))
    assert main(["train", "--prior-fit", "0", "heat_1d", "--data", str(tmp_path / "f32.npz"), "--set", "n=16",
                 "--export-samples", "0", "--out", str(tmp_path / "run")]) == 0
    err = capsys.readouterr().err
    assert "rounding is noise of relative level 6e-08" in err
    assert json.loads((tmp_path / "run" / "run.json").read_text())["overrides"]["noise"] == "6e-08"
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["x_err"] < 0.1


def test_noisy_data_without_a_declared_level_trains_at_the_level_it_shows(tmp_path, capsys):
    """1 % noise, no --set noise: the level is read off the directions outside range(P) (0.0100; the
    Gavish–Donoho estimate says 0.0079 on heat_2d, and a Wiener target 20 % low keeps pure-noise modes:
    x-error 6.6e4 measured), said in one line, recorded in run.json, and the run reaches the oracle-α
    Tikhonov of the same test rows; --set noise=0 is obeyed (and fitting the noise exactly ends
    worse than predicting zero: exit 3, pdeinv.training.verdict)."""
    from pdeinv.training import references

    p = pdeinv.load_problem("heat_2d", n=16, noise=0.01)
    x, y = p.sample(600, 7)
    np.savez(tmp_path / "noisy.npz", y=y, x=x)
    data = ["--data", str(tmp_path / "noisy.npz"), "--set", "n=16", "--export-samples", "0"]
    assert main(["train", "--prior-fit", "0",
                 "heat_2d", *data, "--n-test", "100", "--out", str(tmp_path / "run")]) == 0
    assert "observations show noise of relative level 0.01 " in capsys.readouterr().err
    assert json.loads((tmp_path / "run" / "run.json").read_text())["overrides"]["noise"] == "0.01"
    oracle = references.tikhonov_best(p, y[-100:], x[-100:])["x_err"]
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["x_err"] < oracle
    assert main(["train", "--prior-fit", "0", "heat_2d", *data, "--set", "noise=0", "--steps", "1",
                 "--out", str(tmp_path / "r0")]) == 3
    assert "observations show noise" not in capsys.readouterr().err


def test_a_small_file_says_what_the_default_splits_hold_out(tmp_path, capsys):
    """150 rows and the default --n-test 128: 22 rows train; said in one line, with the way out."""
    p = pdeinv.load_problem("heat_1d", n=16)
    x, y = p.sample(150, 2)
    np.savez(tmp_path / "small.npz", y=y, x=x)
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--data", str(tmp_path / "small.npz"), "--set", "n=16",
                 "--export-samples", "0", "--out", str(tmp_path / "run")]) == 0
    err = said(capsys.readouterr().err)
    assert err == ["pdeinv train: warning: the data's 150 rows: the last 128 are held out as the test set, "
                   "only 22 train; hold out fewer with --n-test (Trainer(n_test=...))"]
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--data", str(tmp_path / "small.npz"), "--set", "n=16", "--n-test", "30",
                 "--export-samples", "0", "--out", str(tmp_path / "run2")]) == 0
    assert said(capsys.readouterr().err) == []


def test_cli_classical_solves_a_data_file(tmp_path, capsys):
    """``pdeinv classical``: Morozov Tikhonov and the Wiener target without x; with x also the oracle α,
    the MMSE fitted on the file's x (no linear solve does better on those rows) and the model mismatch;
    the noise level estimated when the problem declares none."""
    p = pdeinv.load_problem("heat_1d", n=16, noise=0.01)
    x, y = p.sample(200, 5)
    np.savez(tmp_path / "d.npz", y=y, x=x)
    assert main(["classical", "heat_1d", "--data", str(tmp_path / "d.npz"), "--set", "n=16",
                 "--out", str(tmp_path / "c.json")]) == 0
    res = json.loads((tmp_path / "c.json").read_text())
    assert res["rows"] == 200 and res["noise"]["source"] == "estimated from the file"
    assert 0.007 < res["noise"]["level"] < 0.013
    oracle = res["tikhonov_best_common_alpha"]["x_err"]
    assert res["tikhonov_morozov"]["x_err"] < 1.5 * oracle and res["wiener_target"]["x_err"] < 1.1 * oracle
    assert 0.005 < res["model_mismatch"] < 0.011  # the noise itself
    assert 0.005 < res["wiener_target"]["residual"] < 0.02
    assert res["prior_wiener"]["x_err"] < res["wiener_target"]["x_err"]  # the prior fills unseen modes
    assert res["mmse_file_x"]["x_err"] <= 1.02 * min(oracle, res["prior_wiener"]["x_err"])  # the best linear
    assert "heat_1d tikhonov_morozov" in capsys.readouterr().out
    np.savez(tmp_path / "y.npz", y=y)
    assert main(["classical", "heat_1d", "--data", str(tmp_path / "y.npz"), "--set", "n=16",
                 "--set", "noise=0.01"]) == 0
    printed = capsys.readouterr().out
    assert "tikhonov_best_common_alpha" not in printed and "mmse" not in printed


def test_cli_classical_reads_a_clean_file_as_noise_free(tmp_path):
    """A noise-free float64 file whose noise is estimated (2.5e-16, rounding) is noise-free: the level 0,
    no Morozov or Wiener-target row (no noise to fit them to), Tikhonov at the noise-free α, and the
    prior Wiener estimate in its noise-free form, which is what the default network trains to on that
    file (``pdeinv train`` reads it as clean): once the rounding estimate was passed on as a level."""
    from pdeinv.inverse import NOISE_FREE_REL_ALPHA, default_inverse
    from pdeinv.training import references as refs

    p = pdeinv.load_problem("heat_1d", kappa=0.05)
    x, y = pdeinv.load_problem("heat_1d", kappa=0.05, prior="boxes").sample(300, 5)
    np.savez(tmp_path / "clean.npz", y=y, x=x)
    assert main(["classical", "heat_1d", "--set", "kappa=0.05", "--data", str(tmp_path / "clean.npz"),
                 "--out", str(tmp_path / "c.json")]) == 0
    res = json.loads((tmp_path / "c.json").read_text())
    assert res["noise"]["level"] == 0.0 and "noise-free" in res["noise"]["source"]
    assert "tikhonov_morozov" not in res and "wiener_target" not in res
    expected, _ = refs.prior_wiener(p, y, 0.0)
    assert res["prior_wiener"]["x_err"] == pytest.approx(float(np.mean(p.relative_error(expected(y), x))))
    tik = default_inverse(p.operator, p.disc, 0.0)(y, np.zeros_like(x))
    assert res["tikhonov_noise_free"]["alpha_rel"] == NOISE_FREE_REL_ALPHA
    assert res["tikhonov_noise_free"]["x_err"] == pytest.approx(float(np.mean(p.relative_error(tik, x))))


def test_a_file_may_carry_its_points_and_noise_level(tmp_path, capsys):
    """Optional keys: ``points`` must be the problem's (refused, exit 2, naming the largest difference,
    when not); ``noise`` trains at the file's level (in run.json), and a different --set noise is refused."""
    p = pdeinv.load_problem("heat_1d", n=16, noise=0.02)
    x, y = p.sample(160, 3)
    base = ["train", "--prior-fit", "0",
            "heat_1d", "--set", "n=16", "--n-test", "32", "--steps", "2", "--export-samples", "0"]
    np.savez(tmp_path / "ok.npz", y=y, x=x, points=p.points, noise=0.02)
    assert main([*base, "--data", str(tmp_path / "ok.npz"), "--out", str(tmp_path / "run")]) == 0
    assert json.loads((tmp_path / "run" / "run.json").read_text())["overrides"]["noise"] == "0.02"
    assert "observations show noise" not in capsys.readouterr().err  # declared, not estimated
    shifted = p.points.copy()
    shifted[0, 5] += 1e-3
    np.savez(tmp_path / "moved.npz", y=y, points=shifted)
    assert main([*base, "--data", str(tmp_path / "moved.npz"), "--out", str(tmp_path / "r2")]) == 2
    err = capsys.readouterr().err
    assert "points differ from the problem's by up to 0.001 (column 5" in err
    assert not (tmp_path / "r2").exists()
    ok = ["--data", str(tmp_path / "ok.npz")]
    assert main([*base, *ok, "--set", "noise=0.05", "--out", str(tmp_path / "r3")]) == 2
    assert "conflicts with the noise=0.02" in capsys.readouterr().err
    np.savez(tmp_path / "bad.npz", y=y, noise=-1.0)
    assert main([*base, "--data", str(tmp_path / "bad.npz"), "--out", str(tmp_path / "r4")]) == 2
    assert "noise=-1.0 is not allowed" in capsys.readouterr().err
    assert main(["classical", "heat_1d", "--set", "n=16", "--data", str(tmp_path / "ok.npz")]) == 0
    assert "the file's" in capsys.readouterr().out


def test_cli_predict_checks_the_observations_against_the_runs_physics(tmp_path, capsys):
    """Observations of another problem with the same shapes are refused (exit 3, one line, nothing
    written): with x, by the model mismatch (x of other rows); without x, by the noise level the
    observations show outside range(P) (rough fields no heat run can produce). The run's own data:
    accepted, no warning."""
    heat = pdeinv.load_problem("heat_1d", n=64, backend="modal")
    x, y = heat.sample(60, seed=3)
    np.savez(tmp_path / "train.npz", y=y, x=x)
    tail = ["--set", "n=64", "--set", "backend=modal", "--n-test", "10", "--batch-size", "8", "--steps", "2",
            "--export-samples", "0"]
    assert main(["train", "--prior-fit", "0", "heat_1d", "--data", str(tmp_path / "train.npz"), *tail,
                 "--out", str(tmp_path / "run")]) == 0
    rough = np.random.default_rng(0).standard_normal(y.shape)
    files = {"own": dict(y=y, x=x), "own_y": dict(y=y), "shuffled": dict(y=y, x=x[::-1]),
             "rough": dict(y=rough)}
    for name, arrays in files.items():
        np.savez(tmp_path / f"{name}.npz", **arrays)
    capsys.readouterr()
    for name in files:
        out = tmp_path / f"pred_{name}.npz"
        code = main(["predict", str(tmp_path / "run"), "--data", str(tmp_path / f"{name}.npz"),
                     "--out", str(out)])
        err = capsys.readouterr().err.splitlines()
        if name.startswith("own"):
            assert code == 0 and out.exists() and not err, (name, err)
        else:
            assert code == 3 and len(err) == 1 and "is not of this run's physics" in err[0], (name, err)
            assert not out.exists()


def test_cli_reads_read_only_and_unicode_paths_and_refuses_an_unwritable_out(tmp_path, pairs, capsys):
    """Data on a read-only file in a folder with a non-ASCII name trains and predicts (exit 0, the file
    untouched); an --out folder that cannot be written is one line and exit 2 (not as root, who can)."""
    import os
    import stat

    x, y = pairs
    folder = tmp_path / "données ü 数据"
    folder.mkdir()
    data = folder / "obs é.npz"
    np.savez(data, y=y, x=x)
    data.chmod(stat.S_IRUSR)
    before = data.read_bytes()
    run = folder / "run ü"
    # 3 steps on 50 rows: x_err 1.04, kept (--accept-bad): the paths are the point here
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", "--data", str(data), *SMALL, "--accept-bad", "--out", str(run)]) == 0
    assert main(["predict", str(run), "--data", str(data), "--out", str(folder / "préd.npz")]) == 0
    assert data.read_bytes() == before and (folder / "préd.npz").exists()
    if os.geteuid() == 0:
        return
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(stat.S_IRUSR | stat.S_IXUSR)
    capsys.readouterr()
    try:
        code = main(["train", "--prior-fit", "0",
                     "heat_1d", "--data", str(data), *SMALL, "--out", str(locked / "run")])
    finally:
        locked.chmod(stat.S_IRWXU)
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and len(err) == 1 and "locked" in err[0], err


@pytest.mark.parametrize("net", ["whitened", "reduced", "default"])
def test_cli_net_chooses_the_network_and_predict_rebuilds_it(tmp_path, capsys, net):
    """``--net``: the whitened linear map or the prior decoder instead of the problem's default;
    run.json records it and ``predict`` rebuilds the same network (the same predictions)."""
    out = tmp_path / "run"
    assert main(["train", "--prior-fit", "0", "heat_1d", "--net", net, *SMALL, "--out", str(out)]) == 0
    record = json.loads((out / "run.json").read_text())
    assert record["network"]["kind"] == net
    problem, model = pdeinv.load_run(out)
    assert (model.decoder is not None) == (net in ("reduced", "default"))  # heat: the default decodes
    x, y = problem.sample(5, seed=9)
    np.savez(tmp_path / "obs.npz", y=y)
    pred = tmp_path / "p.npz"
    assert main(["predict", str(out), "--data", str(tmp_path / "obs.npz"), "--out", str(pred)]) == 0
    np.testing.assert_allclose(np.load(pred)["x"], pdeinv.io.export.predict(model, y))


def test_cli_net_and_hidden_together_are_refused(tmp_path, capsys):
    code = main(["train", "--prior-fit", "0", "heat_1d", "--net", "reduced", "--hidden", "8", *SMALL,
                 "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and len(err) == 1 and "--net reduced and --hidden 8" in err[0], err
    assert not (tmp_path / "r").exists()
