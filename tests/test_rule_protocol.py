"""A rule written to the minimal protocol is declared once (pdeinv.methods.protocol): what it does not
declare, it does not get; what is not a rule is refused by name."""

from __future__ import annotations

import warnings

import pytest

import pdeinv
from pdeinv.methods.base import Rule
from pdeinv.methods.protocol import Foreign, declared


class Minimal:
    """GD's update written to the three-argument protocol."""

    name = "minimal"

    def __init__(self):
        self.gd = pdeinv.GD(optimizer=pdeinv.sgd(1e-4), normalize=False)
        self.transform = self.gd.transform

    def init(self, problem, model):
        return self.gd.init(problem, model)

    def update(self, state, model, y):
        return self.gd.update(state, model, y)


def test_the_built_in_rules_declare_themselves_and_a_minimal_one_is_wrapped():
    sip = pdeinv.SIP()
    assert declared(sip) is sip and sip.accepts_target and sip.resumable
    mine = declared(Minimal())
    assert isinstance(mine, Foreign) and isinstance(mine, Rule) and mine.name == "minimal"
    assert not mine.accepts_target and not mine.resumable and mine.default_target() is None
    assert mine.data_parallel(None, 2) is None


def test_an_object_that_is_no_rule_is_refused_naming_what_it_lacks():
    class Half:
        def init(self, problem, model): ...

    with pytest.raises(TypeError, match="has no update, transform"):
        declared(Half())


def test_a_minimal_rule_trains_and_on_noisy_data_says_it_fits_the_noise():
    p = pdeinv.load_problem("heat_1d", n=16, noise=0.01)
    with pytest.warns(RuntimeWarning, match="takes no target=.*fits the noisy observations"):
        r = pdeinv.Trainer(p, Minimal(), steps=3, n_train=32, n_test=8, batch_size=8, progress=False,
                           prior=None).fit()
    assert r.metrics["method"] == "minimal"
    clean = pdeinv.load_problem("heat_1d", n=16)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        pdeinv.Trainer(clean, Minimal(), steps=3, n_train=32, n_test=8, batch_size=8, progress=False,
                       prior=None).fit()
