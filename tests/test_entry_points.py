"""The Python entry points take what a user naturally writes, and run what the CLI runs.

* ``pdeinv.train(problem, "sip")`` and ``pdeinv.train("heat_1d", rule)``: names for the rule and the
  problem; ``stop="discrepancy"`` and ``checkpoint="path"`` likewise.
* One preset table (``pdeinv.methods.presets``): ``pdeinv.Trainer(p, pdeinv.SIP())`` takes the steps,
  batch size and network cap that ``pdeinv train --method sip`` takes (issue 36: it ran 1000 steps of
  32 rows against the CLI's 30 full-batch steps).
"""

from __future__ import annotations

import pytest

import pdeinv
from pdeinv.methods.presets import DEFAULT_BATCH, DEFAULT_STEPS, GENERIC, make_rule, run_defaults

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def small():
    return pdeinv.load_problem("heat_1d", n=8)


@pytest.mark.parametrize("method", sorted(GENERIC))
def test_python_defaults_are_the_cli_presets(small, method):
    rule, hp = make_rule(method, small)  # what `pdeinv train --method M` builds
    t = pdeinv.Trainer(small, rule, n_train=64, prior=None)
    assert t.steps == (hp.get("steps") or DEFAULT_STEPS)
    assert t.batch_size == (64 if hp["batch_size"] is None else hp["batch_size"])
    assert t._network_settings().get("rows_per_component") == hp["rows_per_component"]


def test_sip_runs_thirty_full_batch_steps_in_python_as_on_the_command_line(small):
    t = pdeinv.Trainer(small, pdeinv.SIP(), n_train=64, prior=None)
    assert (t.steps, t.batch_size) == (30, 64)
    assert pdeinv.Trainer(small, pdeinv.SIP(), time_budget=5.0,
                          prior=None).steps is None  # the budget alone ends it
    assert pdeinv.Trainer(small, pdeinv.SIP(), steps=7, batch_size=8, prior=None).steps == 7  # given: kept


def test_a_rule_outside_the_table_keeps_the_generic_defaults(small):
    class Mine(pdeinv.GD):
        pass

    rule = Mine(name="mine")
    expected = {"steps": DEFAULT_STEPS, "batch_size": DEFAULT_BATCH, "rows_per_component": None}
    assert run_defaults(rule) == expected


def test_hig_on_an_mlp_takes_the_cli_batch(small):
    from pdeinv.methods.presets import HIG_MLP_BATCH
    from pdeinv.nets import MLP

    mlp = MLP(small.operator.n_out, small.N, hidden=(8,))
    assert pdeinv.Trainer(small, pdeinv.HIG(), mlp, n_train=64, prior=None).batch_size == HIG_MLP_BATCH
    assert pdeinv.Trainer(small, pdeinv.HIG(), n_train=64,
                          prior=None).batch_size == 64  # the default network: all rows


def test_names_for_the_rule_the_problem_the_stop_and_the_checkpoint(small, tmp_path):
    by_name = pdeinv.train("heat_1d", "sip", n_train=16, n_test=8, steps=2, progress=False,
                           stop="discrepancy", checkpoint=tmp_path / "c.pt", prior=None)
    assert by_name.metrics["steps"] == 2 and (tmp_path / "c.pt").is_file()
    t = pdeinv.Trainer(small, "adam", n_train=64, prior=None)
    assert t.rule.name == "adam" and t.batch_size == 32 and t.steps == 1000
    assert isinstance(pdeinv.Trainer(small, "sip", stop="none", prior=None).stop, type(None))


def test_train_has_a_docstring_and_typed_signature():
    import inspect

    assert len(inspect.getdoc(pdeinv.train).splitlines()) > 3
    sig = inspect.signature(pdeinv.train)
    assert sig.parameters["rule"].annotation != inspect.Parameter.empty
