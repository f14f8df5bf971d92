"""Checkpoints: a resumed run repeats the uninterrupted one bitwise (same machine, same thread
counts; HIG's kept-rows route to rounding), files are replaced atomically, and a checkpoint of
another run is refused naming both."""

from __future__ import annotations

import math

import pytest
import torch

import pdeinv
from pdeinv import Checkpoint, Trainer
from pdeinv.methods import GD, HIG, SIP, adam, sgd
from pdeinv.nets import MLP
from pdeinv.training.checkpoint import history_rows

pytestmark = pytest.mark.usefixtures("one_thread")  # small dense work: one torch thread


def trainer(problem, rule, steps, ckpt=None, resume=False, hidden=(16,), **kw):
    torch.manual_seed(0)
    model = MLP(problem.operator.n_out, problem.operator.n_in, hidden=hidden)
    kw = {"n_train": 24, "n_test": 16, "batch_size": 8, "eval_every": 4, **kw}  # 3 batches an epoch
    return Trainer(problem, rule, model, steps=steps, progress=False, checkpoint=ckpt, resume=resume,
                   **{"prior": None, **kw})


def losses(result):
    return [(h["step"], h["loss"], h.get("x_err"), h.get("y_err")) for h in result.history]


@pytest.mark.parametrize("rule", [GD(sgd(0.05)), GD(adam(1e-3), name="adam"), SIP(optimizer=adam(1e-3)),
                                  HIG(eta=0.1, tau=1e-5),
                                  HIG(eta=0.1, tau=1e-5, route="randomized", probes=6)],
                         ids=["gd", "adam", "sip", "hig", "hig-randomized"])
def test_resumed_run_equals_the_uninterrupted_one_bitwise(heat, rule, tmp_path):
    steps = 6 if rule.name == "hig" else 10
    ref = trainer(heat, rule, steps).fit()
    ckpt = Checkpoint(tmp_path / "c.pt", every=3)

    def kill(record, model):
        if record["step"] == steps - 1:
            raise KeyboardInterrupt  # "killed" during the step before the last, after its update

    with pytest.raises(KeyboardInterrupt):
        trainer(heat, rule, steps, ckpt, callbacks=[kill]).fit()
    assert ckpt.load()["position"]["step"] == 3 * ((steps - 2) // 3)
    resumed = trainer(heat, rule, steps, ckpt, resume=True).fit()
    assert losses(resumed) == losses(ref)  # bitwise: floats compared with ==
    assert all(torch.equal(a, b) for a, b in zip(ref.model.state_dict().values(),
                                                 resumed.model.state_dict().values()))
    timing = ("step_s", "setup", "setup_cpu")  # seconds, not results

    def results(m):
        stages = [{k: v for k, v in st.items() if k != "seconds"} for st in m["stages"]]
        return {**{k: v for k, v in m.items() if "wall" not in k and k not in timing}, "stages": stages}

    assert results(resumed.metrics) == results(ref.metrics)
    assert ckpt.load()["position"]["step"] == steps


def test_resuming_a_finished_run_returns_it_and_more_steps_extend_it(heat, tmp_path):
    ckpt = Checkpoint(tmp_path / "c.pt", every=100)
    done = trainer(heat, GD(adam(1e-3)), 5, ckpt).fit()
    again = trainer(heat, GD(adam(1e-3)), 5, ckpt, resume=True).fit()
    assert losses(again) == losses(done) and again.metrics["x_err"] == done.metrics["x_err"]
    longer = trainer(heat, GD(adam(1e-3)), 8, ckpt, resume=True).fit()
    ref = trainer(heat, GD(adam(1e-3)), 8).fit()
    assert [h["loss"] for h in longer.history] == [h["loss"] for h in ref.history]
    assert longer.metrics["x_err"] == ref.metrics["x_err"]


def test_global_rng_states_are_restored(heat, tmp_path):
    import random

    import numpy as np

    ckpt = Checkpoint(tmp_path / "c.pt", every=1)
    trainer(heat, GD(adam(1e-3)), 3, ckpt).fit()
    after = (torch.rand(3), np.random.rand(3), random.random())
    torch.manual_seed(123), np.random.seed(123), random.seed(123)
    trainer(heat, GD(adam(1e-3)), 3, ckpt, resume=True).fit()
    again = (torch.rand(3), np.random.rand(3), random.random())
    assert torch.equal(after[0], again[0]) and (after[1] == again[1]).all() and after[2] == again[2]


@pytest.mark.parametrize("change, match", [
    (dict(problem=("wave_1d", dict(n=16, steps=10))),
     r"checkpoint '.*c\.pt' is of problem 'heat_1d', this run is 'wave_1d'"),
    (dict(problem=("heat_1d", dict(n=16, steps=10, kappa=0.02, backend="modal"))),
     r"other settings: kappa=0\.01 \(checkpoint\) vs 0\.02 \(this run\)"),
    (dict(hidden=(8,)), r"holds network MLP \(.*body\.0\.weight \(16, 15\).*this run's network is "
                        r"MLP \(.*body\.0\.weight \(8, 15\)"),
    (dict(rule=SIP()), r"written with rule 'gd'; this run has 'sip'"),
    (dict(seed=1), r"written with other data settings: seed=0 \(checkpoint\) vs 1 \(this run\) \(--seed\); "),
])
def test_a_checkpoint_of_another_run_is_refused_naming_both(heat, tmp_path, change, match):
    ckpt = Checkpoint(tmp_path / "c.pt", every=1)
    trainer(heat, GD(adam(1e-3)), 2, ckpt).fit()
    before = ckpt.path.read_bytes()
    name, over = change.pop("problem", ("heat_1d", dict(n=16, steps=10, backend="modal")))
    t = trainer(pdeinv.load_problem(name, **over), change.pop("rule", GD(adam(1e-3))), 4, ckpt,
                resume=True, **change)
    with pytest.raises(ValueError, match=match):
        t.fit()
    assert ckpt.path.read_bytes() == before  # a refused run leaves the checkpoint alone


def test_another_rule_and_network_is_named_in_a_short_line(heat, tmp_path):
    """Another rule with another network: the rule is named (it is what the user changed), not a dump of
    both networks (1-3 kB before); another network names at most a few differences."""
    ckpt = Checkpoint(tmp_path / "c.pt", every=1)
    trainer(heat, GD(adam(1e-3)), 2, ckpt, hidden=(16, 16, 16)).fit()
    with pytest.raises(ValueError) as info:
        trainer(heat, SIP(), 4, ckpt, resume=True, hidden=(8,)).fit()
    message = str(info.value)
    assert "written with rule 'gd'; this run has 'sip'" in message and len(message) < 250, message
    with pytest.raises(ValueError) as info:
        trainer(heat, GD(adam(1e-3)), 4, ckpt, resume=True, hidden=(8,)).fit()
    message = str(info.value)
    assert "holds network MLP (" in message and "more" in message and len(message) < 700, message
    assert "\n" not in message


def test_missing_and_corrupt_checkpoints(heat, tmp_path):
    ckpt = Checkpoint(tmp_path / "c.pt")
    with pytest.raises(FileNotFoundError, match=r"no checkpoint at '.*c\.pt' to resume from"):
        trainer(heat, GD(), 2, ckpt, resume=True).fit()
    with pytest.raises(ValueError, match="resume=True needs checkpoint="):
        trainer(heat, GD(), 2, None, resume=True)
    trainer(heat, GD(), 2, Checkpoint(ckpt.path, every=1)).fit()
    good = ckpt.path.read_bytes()
    scrambled = good[:100] + b"\0" * 100 + good[200:]
    for bad in (good[: len(good) // 2], b"", b"not a checkpoint at all", scrambled):
        ckpt.path.write_bytes(bad)
        with pytest.raises(ValueError, match=r"checkpoint '.*c\.pt' is corrupt or not a pdeinv checkpoint"):
            ckpt.load()
    torch.save({"something": 1}, ckpt.path)
    with pytest.raises(ValueError, match="is not a pdeinv checkpoint"):
        ckpt.load()
    ckpt.save({"model": {}})  # a pdeinv file, but not a training run's
    with pytest.raises(ValueError, match="lacks history, identity, position, rng, rule_state"):
        trainer(heat, GD(), 2, ckpt, resume=True).fit()


def test_save_is_atomic_and_cleans_up_after_a_killed_save(tmp_path):
    ckpt = Checkpoint(tmp_path / "c.pt")
    ckpt.save({"n": 1})
    stale = tmp_path / ".c.pt.abc123.tmp"  # what a save killed halfway leaves
    stale.write_bytes(b"half")

    class Boom:
        def __reduce__(self):
            raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):  # a save failing halfway ...
        ckpt.save({"n": 2, "x": Boom()})
    assert ckpt.load()["n"] == 1  # ... leaves the previous checkpoint
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.pt"]  # and no temporaries
    ckpt.save({"n": 3})
    assert ckpt.load()["n"] == 3


def test_rules_without_state_dict_cannot_be_checkpointed(heat, tmp_path):
    from pdeinv.methods import State, Update
    from pdeinv.methods.transforms import Add

    class Frozen:
        name = "frozen"
        transform = Add()

        def init(self, problem, model):
            return State(None)

        def update(self, state, model, y):
            return Update(tuple(None for _ in model.parameters()), {"loss": 1.0})  # no change

    with pytest.raises(ValueError, match="'frozen' cannot be checkpointed.*Resumable"):
        trainer(heat, Frozen(), 2, Checkpoint(tmp_path / "c.pt")).fit()


def test_a_resumed_default_hig_run_agrees_with_the_uninterrupted_one_to_rounding(heat, tmp_path):
    """HIG's kept-rows route (pdeinv.methods.hig.fixed) carries its residual between steps outside the
    checkpoint: a resumed run recomputes it, so it agrees with the uninterrupted run to rounding, not
    bitwise (the one documented exception)."""
    def run(ckpt=None, resume=False, callbacks=()):
        torch.manual_seed(0)
        return Trainer(heat, HIG(), heat.model(), steps=8, n_train=24, n_test=16, batch_size=None,
                       eval_every=4, progress=False, checkpoint=ckpt, resume=resume,
                       callbacks=list(callbacks), prior=None).fit()

    ref = run()

    def kill(record, model):
        if record["step"] == 7:
            raise KeyboardInterrupt

    ckpt = Checkpoint(tmp_path / "c.pt", every=3)
    with pytest.raises(KeyboardInterrupt):
        run(ckpt, callbacks=[kill])
    resumed = run(ckpt, resume=True)
    for a, b in zip(losses(ref), losses(resumed), strict=True):
        assert a[0] == b[0] and a[1] == pytest.approx(b[1], rel=1e-9, abs=1e-30)
    assert resumed.metrics["x_err"] == pytest.approx(ref.metrics["x_err"], rel=1e-9)


def test_history_columns_give_back_the_rows_and_save_in_time_independent_of_python_rows():
    """A checkpoint's history is stored as columns (:func:`history_columns`): the same rows come back
    (ints stay ints, NaN stays NaN, a rejected step's message and a key only some rows have), and a
    long history saves as a few tensors, not one pickled dict per row."""
    import io
    import math

    from pdeinv.training.checkpoint import HistoryColumns, history_columns, history_rows
    from pdeinv.util.files import same_row

    rows = [{"step": i, "wall_s": 0.01 * i, "loss": 1.0 / i, **({"x_err": 0.5 / i} if i % 3 == 0 else {})}
            for i in range(1, 2001)]
    rows[10] = {"step": 11, "wall_s": 0.11, "loss": math.nan, "rejected": "step 11 (sip): NaN"}
    rows[20]["stopped"] = None
    buffer = io.BytesIO()
    torch.save({"history": history_columns(rows)}, buffer)
    buffer.seek(0)
    back = history_rows(torch.load(buffer, weights_only=True)["history"])
    assert len(back) == len(rows)
    for a, b in zip(back, rows, strict=True):
        assert a.keys() == b.keys()
        for k in a:
            assert type(a[k]) is type(b[k]) and (a[k] == b[k] or (math.isnan(a[k]) and math.isnan(b[k])))
    assert history_rows(rows) is rows  # a history saved as rows (older checkpoints) loads as it is
    saved = history_columns(rows)
    assert history_rows(saved, 1500) == history_rows(saved)[1500:] and history_rows(saved, 2000) == []
    assert all(same_row(a, b) for a, b in zip(history_rows(saved, 5), rows[5:], strict=True))
    grown = HistoryColumns()
    grown(rows[:700])
    assert grown([*rows[:699], {"step": 700, "loss": 2.0}])["rows"] == 700  # a changed last row: over
    assert all(same_row(a, b) for a, b in zip(history_rows(grown(rows)), rows, strict=True))  # grown by
    # the new rows only
    with pytest.raises(ValueError, match="not a pdeinv run's history"):
        history_rows({"rows": 3, "columns": {"step": (torch.tensor([0, 7]), torch.tensor([1, 2]))}})
    columns = history_columns(rows)["columns"]
    assert isinstance(columns["loss"][1], torch.Tensor) and columns["loss"][1].dtype == torch.float64
    assert columns["step"][1].dtype == torch.int64 and isinstance(columns["rejected"][1], list)


def test_history_csv_grows_by_appending_and_reads_as_a_full_rewrite(tmp_path):
    """:class:`pdeinv.util.files.CsvLog`: appended rows give the text a full write gives; a new key, a
    changed last row or a shorter history rewrite the file (and a deleted file is written again)."""
    from pdeinv.util.files import CsvLog, write_csv

    log, path, ref = CsvLog(tmp_path / "h.csv"), tmp_path / "h.csv", tmp_path / "ref.csv"
    rows = []

    def same():
        write_csv(rows, ref)
        return path.read_text() == ref.read_text()

    for i in range(1, 40):
        rows.append({"step": i, "loss": 1.0 / i, "x_err": 0.1 * i})
        if i % 7 == 0:
            log.write(len(rows), lambda start: rows[start:])
            assert same()
    rows.append({"step": 40, "loss": 0.1, "plateau": 0.5})  # a new key: the header changes
    log.write(len(rows), lambda start: rows[start:])
    assert same() and "plateau" in path.read_text().splitlines()[0]
    rows[-1] = {**rows[-1], "x_err": 9.0}  # the last row written changed (the final evaluation)
    log.write(len(rows), lambda start: rows[start:])
    assert same()
    del rows[30:]  # a resumed run's history from an earlier checkpoint
    log.write(len(rows), lambda start: rows[start:])
    assert same()
    path.unlink()
    rows.append({"step": 31, "loss": 0.2, "x_err": 1.0})
    log.write(len(rows), lambda start: rows[start:])
    assert same()


def test_resumed_past_its_time_budget_ends_evaluated(heat, tmp_path):
    """A checkpoint of an unevaluated step resumed with a time budget it has already spent trains no
    step, and its last record is evaluated for metrics.json (it was a KeyError on 'y_err')."""
    ckpt = Checkpoint(tmp_path / "c.pt", every=3)

    def kill(record, model):
        if record["step"] == 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        trainer(heat, GD(sgd(0.05)), 1000, ckpt, callbacks=[kill], eval_every=100).fit()
    saved = history_rows(ckpt.load()["history"])
    assert len(saved) == 3 and "y_err" not in saved[-1]
    resumed = trainer(heat, GD(sgd(0.05)), None, ckpt, resume=True, time_budget=1e-9,
                      eval_every=100).fit()
    assert resumed.metrics["steps"] == 3 and resumed.metrics["stopped_by"] == "time_budget"
    assert math.isfinite(resumed.metrics["y_err"]) and math.isfinite(resumed.metrics["x_err"])
