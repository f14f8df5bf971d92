"""Bad input to the Python API, found by a fuzz round: each is refused with a ``ValueError`` or
``TypeError`` in one line naming the argument, not an ``AttributeError``, a torch or numpy error from deep
inside, a run written that loads no more, or another run's files replaced."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.nets import MLP
from pdeinv.posterior import Calibration, predictive
from pdeinv.util.runlock import RunLock


@pytest.fixture(scope="module")
def heat():
    return pdeinv.load_problem("heat_1d", n=16)


@pytest.fixture(scope="module")
def net(heat):
    torch.manual_seed(0)
    return MLP(heat.operator.n_out, heat.N, hidden=(8,))


@pytest.fixture(scope="module")
def posterior(heat):
    rng = np.random.default_rng(0)
    return Calibration.fit(rng.normal(size=(8, heat.N)), rng.normal(size=(8, heat.N)))


def one_line(err) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


def save(out, heat, net, **kw):
    return pdeinv.save_run(out, "heat_1d", {"n": 16}, {"kind": "mlp", "hidden": [8]}, model=net, **kw)


@pytest.mark.parametrize("kw, error, match", [
    ({"hidden": [0]}, ValueError, r"^hidden=\[0\] is not allowed; expected a list of integer widths >= 1"),
    ({"hidden": "64,64"}, TypeError, r"^hidden='64,64' is str; expected a list of integer widths"),
    ({"n_train": 0}, ValueError, r"^n_train=0 is not allowed; expected an integer >= 2"),
    ({"steps": -1}, ValueError, r"^steps=-1 is not allowed; expected an integer >= 1"),
    ({"batch_size": 0}, ValueError, r"^batch_size=0 is not allowed; expected an integer >= 1"),
    ({"n_test": -1}, ValueError, r"^n_test=-1 is not allowed; expected an integer >= 1"),
    ({"batch_size": 64, "n_train": 8}, ValueError, r"^batch_size=64 is larger than n_train=8"),
    ({"own": 5}, TypeError, r"^own=5 is int; expected None or the user's rows"),
    ({"net": "foo"}, ValueError, r"^net='foo' is not allowed; expected one of 'default', "),
    ({"net": "unet", "hidden": [8]}, ValueError, r"^net='unet' and hidden=\[8\] choose two networks"),
])
def test_plan_refuses_what_the_trainer_refuses(heat, kw, error, match):
    with pytest.raises(error, match=match) as err:
        pdeinv.plan(heat, **kw)
    one_line(err)


def test_plan_still_plans(heat):
    assert pdeinv.plan(heat, hidden=[8], steps=2, batch_size=4, n_train=8, n_test=4).network["kind"] == "mlp"


def test_predictive_refuses_a_wrong_posterior_y_or_sample_count(heat, net, posterior, monkeypatch):
    y = heat.sample(4)[1]
    assert predictive(net, posterior, y, samples=2)["samples"].shape == (4, 2, heat.N)
    with pytest.raises(TypeError, match=r"^posterior=5 is int; expected a pdeinv.posterior.Calibration"):
        predictive(net, 5, y)
    with pytest.raises(TypeError, match=r"^model=None is NoneType; expected a torch.nn.Module"):
        predictive(None, posterior, y)
    with pytest.raises(ValueError, match=r"^y has shape \(4, 4\); the network does not take 4 observations .*"
                                         r"expected \(B, m\)") as err:
        predictive(net, posterior, y[:, :4])
    one_line(err)
    with pytest.raises(ValueError, match=rf"^y has shape \(4, 4\); expected \(B, {heat.operator.n_out}\)"):
        predictive(net, posterior, y[:, :4], problem=heat)
    kept = len(posterior.residuals)  # every sample is one of the kept residuals
    with pytest.raises(ValueError, match=rf"^samples=1000000000 is not allowed: the posterior keeps {kept} "
                                         rf"residuals, each sample is one of them; expected at most {kept}"):
        predictive(net, posterior, y, samples=10**9)
    with pytest.raises(ValueError, match=r"^seed=-1 is not allowed; expected an integer from 0 to"):
        predictive(net, posterior, y, samples=2, seed=-1)
    monkeypatch.setenv("PDEINV_MAX_MEMORY_GB", "1e-6")
    with pytest.raises(ValueError, match=rf"^predictive\(samples={kept}\) \(400 x {kept} x \d+ float64 "
                                         r"draws\) needs about .* GB of memory, above the budget of 1e-06"):
        predictive(net, posterior, np.repeat(y, 100, axis=0), samples=kept)


def test_a_problem_refuses_bad_parts_and_sizes(heat, monkeypatch):
    parts = {"name": "q", "disc": heat.disc, "operator": heat.operator, "sampler": heat.sampler}
    for noise, match in ((-1, r"^noise=-1 is not allowed; expected a number >= 0"),
                         (float("nan"), r"^noise=nan is not allowed; expected a finite number >= 0")):
        with pytest.raises(ValueError, match=match):
            pdeinv.Problem(**parts, noise=noise)
    with pytest.raises(TypeError, match=r"^sampler=5 is int; expected a function sampler\(n, rng\)"):
        pdeinv.Problem(**{**parts, "sampler": 5})
    assert pdeinv.Problem(**{**parts, "sampler": None}).sampler is None  # no prior: allowed
    monkeypatch.setenv("PDEINV_MAX_MEMORY_GB", "1")
    with pytest.raises(ValueError, match=r"^problem 'heat_1d': sample\(n=1099511627776\) .* needs about "
                                         r".* GB of memory, above the budget of 1 GB"):
        heat.sample(2**40)
    x = heat.sample(4)[0]
    with pytest.raises(ValueError, match=rf"^xhat has shape \(3, {heat.N}\) but x has \(4, {heat.N}\)"):
        heat.relative_error(x[:3], x)
    assert heat.relative_error(x[:1], x).shape == (4,)  # one row against many: as before


@pytest.mark.parametrize("value", [None, 5, b"/tmp"], ids=["None", "int", "bytes"])
def test_paths_must_be_paths(value):
    name = {type(None): "NoneType", int: "int", bytes: "bytes"}[type(value)]
    with pytest.raises(TypeError, match=rf"^run_dir={value!r} is {name}; expected a path \(str or "
                                        r"os.PathLike\)"):
        pdeinv.load_run(value)
    if not isinstance(value, bytes):
        with pytest.raises(TypeError, match=rf"^path={value!r} is {name}; expected a path \(str or "
                                            r"os.PathLike\)"):
            pdeinv.Checkpoint(value)


def test_save_run_refuses_what_load_run_would(heat, net, posterior, tmp_path):
    with pytest.raises(ValueError, match=r"overrides=\{'nope': 1\} does not load \(unknown setting\(s\) "
                                         r"'nope'"):
        pdeinv.save_run(tmp_path / "a", heat, overrides={"nope": 1}, model=net)
    other = pdeinv.load_problem("heat_2d", n=8)
    with pytest.raises(ValueError, match=r"^model does not take this problem's \d+ observations per row"):
        pdeinv.save_run(tmp_path / "b", other, {"n": 8}, model=net)
    with pytest.raises(TypeError, match=r"^posterior=5 is int; expected None or a pdeinv.posterior."
                                        r"Calibration"):
        save(tmp_path / "c", heat, net, posterior=5)
    wide = Calibration.fit(np.ones((2, 5)), np.ones((2, 5)))
    with pytest.raises(ValueError, match=rf"^posterior is for 5 unknowns; the run's problem has {heat.N}"):
        save(tmp_path / "d", heat, net, posterior=wide)
    assert not any((tmp_path / n).exists() for n in "abcd")  # refused before anything is written


def test_save_run_replaces_another_run_only_with_overwrite(heat, net, posterior, tmp_path):
    run = save(tmp_path / "r", heat, net, posterior=posterior)
    before = (run / "model.pt").read_bytes()
    with pytest.raises(ValueError, match=r"holds another pdeinv run \(model.pt, run.json, posterior.npz\); "
                                         r"pass overwrite=True to replace it"):
        save(run, heat, MLP(heat.operator.n_out, heat.N, hidden=(8,)))
    assert (run / "model.pt").read_bytes() == before and (run / "posterior.npz").is_file()
    with pytest.raises(TypeError, match=r"^overwrite='yes' is str; expected True or False"):
        save(run, heat, net, overwrite="yes")
    save(run, heat, net, overwrite=True)
    assert not (run / "posterior.npz").exists()  # the earlier run's: not this model's
    with RunLock(run), pytest.raises(ValueError, match="overwrite=True"):  # a lock is no permission
        save(run, heat, net)
    assert pdeinv.load_run(run)[0].N == heat.N


@pytest.mark.parametrize("field, value, match", [
    ("overrides", [1, 2], r"run\.json's 'overrides' is \[1, 2\]; expected an object of the problem's "),
    ("network", None, r"run\.json's 'network' is null; expected an object with 'kind' one of 'default'"),
    ("problem", 5, r"run\.json's 'problem' is 5; expected the problem's name or module path"),
    ("network", {"kind": "mlp", "hidden": None}, r"run\.json's 'network' .* builds no network"),
    ("overrides", {"n": "32"}, r"run\.json was edited after the run \(.*; its settings now build another "
                               r"problem: it now has 31 unknowns, the run's had 15\)"),
], ids=["overrides-list", "network-null", "problem-int", "network-settings", "overrides-n"])
def test_load_run_names_the_field_of_an_edited_run_json(heat, net, tmp_path, field, value, match):
    run = save(tmp_path / "r", heat, net)
    record = json.loads((run / "run.json").read_text())
    (run / "run.json").write_text(json.dumps({**record, field: value}))
    with pytest.raises(ValueError, match=match) as err:
        pdeinv.load_run(run)
    assert "MLP" not in one_line(err) and "state_dict" not in str(err.value)


def test_apply_names_an_operator_that_is_none():
    with pytest.raises(TypeError, match=r"op=None is NoneType; expected a pdeinv operator"):
        pdeinv.apply(None, torch.zeros(3, 63))
