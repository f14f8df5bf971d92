"""The energy a trained network puts where the physics cannot see (pdeinv.training.verdict), against the
prior's."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import pdeinv
from pdeinv import nets
from pdeinv.methods import GD, sgd
from pdeinv.training.verdict import FACTOR, SLACK, unseen_energy

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def heat():
    return pdeinv.load_problem("heat_1d", n=64, backend="modal")


def test_the_truth_and_its_seen_part_pass_and_invented_energy_is_named(heat):
    """The prior's own samples carry exactly the prior's unseen energy; their seen part none; the
    same samples with energy added outside the seen directions above FACTOR× the prior's (and SLACK
    of its total): warned, naming the number of unseen directions."""
    x, _ = heat.sample(64, seed=1)
    g = heat.operator.modes.g
    keep = g > 1e-12 * g.max()
    Q = np.linalg.qr(heat.operator.modes.In[:, keep])[0]
    record, warning = unseen_energy(heat, x, x)
    assert warning is None and record["prediction"] == pytest.approx(record["prior"])
    assert record["seen"] == keep.sum() < heat.N
    seen = (x @ Q) @ Q.T
    record, warning = unseen_energy(heat, seen, x)
    assert warning is None and record["prediction"] < 1e-20 * record["prior"]
    rng = np.random.default_rng(0)
    junk = rng.standard_normal(x.shape)
    junk -= (junk @ Q) @ Q.T
    bound = FACTOR * record["prior"] + SLACK * np.mean(np.sum(x**2, 1))
    junk *= np.sqrt(2 * bound / np.mean(np.sum(junk**2, 1)))
    record, warning = unseen_energy(heat, x + junk, x)
    assert warning is not None and f"{heat.N - keep.sum()} directions" in warning
    assert record["prediction"] > FACTOR * record["prior"]


def test_an_invertible_physics_has_nothing_unseen():
    wave = pdeinv.load_problem("wave_1d", n=16)
    x, _ = wave.sample(8, seed=0)
    assert unseen_energy(wave, 10 * x, x) == (None, None)


def test_a_run_whose_weights_never_moved_there_is_warned_about(heat):
    """A whitened linear map started from large random weights: gradient steps never move its output
    where P is blind (P's null space gets no gradient), so the predictions keep the random start there:
    recorded in metrics.json and warned about once; the default network and rule: no warning."""
    model = nets.whitened("linear")(heat)
    torch.manual_seed(0)
    with torch.no_grad():
        for p in model.parameters():
            p.normal_(0, 1.0)
    with pytest.warns(RuntimeWarning, match="directions the physics cannot see"):
        r = pdeinv.train(heat, GD(optimizer=sgd(1e-3)), model, steps=2, n_train=64, n_test=16,
                         batch_size=16, progress=False, prior=None)
    assert r.metrics["unseen_energy"]["prediction"] > FACTOR * r.metrics["unseen_energy"]["prior"]
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        r = pdeinv.train(heat, pdeinv.SIP(), steps=3, n_train=64, n_test=16, batch_size=None, progress=False,
                         prior=None)
    assert r.metrics["unseen_energy"]["prediction"] <= FACTOR * r.metrics["unseen_energy"]["prior"]
