"""Data-parallel training (:mod:`pdeinv.training.distributed`): the torchrun contract and its refusals.

* Two processes (gloo, one thread each) train the same run as one process: the per-step
  losses and the final x/y errors agree to float tolerance, for GD and SIP. The GD run goes
  through ``torchrun --standalone --nproc_per_node=2 -m pdeinv train …`` (the contract);
  the others start the two ranks directly with torchrun's environment variables
  (``RANK``, ``WORLD_SIZE``, ``MASTER_ADDR``/``PORT``), which is the same code path and
  saves torchrun's own start-up.
* A rank that dies at a chosen step ends the run with one line and exit 1 instead of a
  hang, and ``--resume`` continues from the last checkpoint to the uninterrupted result.
* Bad input (ranks started with different command lines, a global batch that does not
  split over the processes, HIG on two processes, ``--device cuda`` without CUDA) gets one
  line, exit 2, and nothing is written.

Budget: each process pays ~3-5 s of imports (torch) on the shared 2-core machine.
"""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from stderr import said

import pdeinv
from pdeinv.cli import main
from pdeinv.training import distributed
from pdeinv.training.distributed import DataParallel, Single

ROOT = Path(__file__).resolve().parents[1]
RUN = ["train", "--prior-fit", "0",
       "heat_1d", "--set", "n=16", "--set", "steps=10", "--hidden", "16", "--steps", "12",
       "--n-train", "64", "--n-test", "16", "--batch-size", "8", "--eval-every", "4", "--seed", "3",
       "--export-samples", "0", "--threads", "1"]
#: ``python FAULT MODE RANK STEP ARGV…``: on rank RANK at its STEP-th step, ``exit`` dies (os._exit(9))
#: right after the update; ``nan`` makes that step's shard loss NaN (GD/Adam's y-loss), on that rank only
FAULT = """import importlib, math, os, sys
guard = importlib.import_module("pdeinv.methods.guard")  # the Guard applies every update through it
gd = importlib.import_module("pdeinv.methods.gd")
mode, rank, step = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
mine = int(os.environ["RANK"]) == rank
real_step, real_loss, calls = guard.apply_if_finite, gd.y_loss, {"step": 0, "loss": 0}
def apply_if_finite(*a, **kw):
    out = real_step(*a, **kw)
    calls["step"] += 1
    if mine and mode == "exit" and calls["step"] == step:
        os._exit(9)
    return out
def y_loss(*a):
    calls["loss"] += 1
    value = real_loss(*a)
    return value * math.nan if mine and mode == "nan" and calls["loss"] == step else value
guard.apply_if_finite, gd.y_loss = apply_if_finite, y_loss
from pdeinv.cli import main
sys.exit(main(sys.argv[4:]))
"""


def _env(rank: int = 0, port: int | None = None) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "PDEINV_DDP_TIMEOUT": "60"}
    if port is not None:
        env.update(RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE="2", LOCAL_WORLD_SIZE="2",
                   MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    return env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _two_ranks(argv0: list, argv1: list | None = None, script: list | None = None,
               retried: bool = False) -> list:
    """Start ranks 0 and 1 as torchrun would (its environment), wait, return ``(code, stderr)`` each."""
    port, head = _free_port(), script or ["-m", "pdeinv"]
    procs = [subprocess.Popen([sys.executable, *head, *argv], cwd=ROOT, env=_env(rank, port),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for rank, argv in enumerate((argv0, argv1 or argv0))]
    ranks = [(p.wait(timeout=180), p.communicate()[1]) for p in procs]
    if -signal.SIGABRT in [code for code, _ in ranks] and not retried:  # no test expects an abort: gloo's
        # transport (as in the torchrun test; twice in the full suite on 2026-11-27, at most one other job
        # running: "terminate called without an active exception" at a rank's exit; alone, every run
        # passed): once more
        return _two_ranks([*argv0, "--overwrite"], argv1 and [*argv1, "--overwrite"], script, retried=True)
    return ranks


def _nothing_in(out: Path) -> bool:
    """No file in ``out`` (the checkpoint proves its folder writable up front, so it may exist)."""
    return not out.exists() or not any(out.iterdir())


def _history(out: Path) -> list:
    with open(out / "history.csv") as fh:
        return [float(r["loss"]) for r in csv.DictReader(fh)]


def _single(out: Path, *extra) -> dict:
    assert main([*RUN, *extra, "--out", str(out)]) == 0
    return json.loads((out / "metrics.json").read_text())


def _same_run(one: Path, two: Path) -> None:
    a, b = json.loads((one / "metrics.json").read_text()), json.loads((two / "metrics.json").read_text())
    assert (a["world_size"], b["world_size"]) == (1, 2)
    assert a["steps"] == b["steps"] == 12
    for key in ("x_err", "y_err", "loss"):
        assert b[key] == pytest.approx(a[key], rel=1e-5), key
    assert _history(two) == pytest.approx(_history(one), rel=1e-5)


@pytest.mark.slow
def test_torchrun_two_processes_train_as_one_gd(tmp_path):
    _single(tmp_path / "one", "--method", "gd")
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
           "-m", "pdeinv", *RUN, "--method", "gd", "--out", str(tmp_path / "two")]
    done = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=180)
    if done.returncode != 0 and "(SIGABRT)" in done.stderr:  # a rank killed by gloo's transport on a loaded
        # machine (seen once in CI, 2026-11-27, beside two training runs; not reproduced in 5 runs): once more
        first = done.stderr
        done = subprocess.run(cmd + ["--overwrite"], cwd=ROOT, env=_env(), capture_output=True, text=True,
                              timeout=180)
        assert done.returncode == 0, first[:2000] + "\n...\n" + done.stderr[-2000:]
    assert done.returncode == 0, done.stderr[:1000] + "\n...\n" + done.stderr[-2000:]
    _same_run(tmp_path / "one", tmp_path / "two")


def test_two_processes_train_as_one_sip(tmp_path):
    _single(tmp_path / "one", "--method", "sip")
    ranks = _two_ranks([*RUN, "--method", "sip", "--out", str(tmp_path / "two")])
    assert [code for code, _ in ranks] == [0, 0], "\n".join(err[-2000:] for _, err in ranks)
    _same_run(tmp_path / "one", tmp_path / "two")


def test_a_dead_rank_ends_the_run_and_resume_finishes_it(tmp_path):
    out = tmp_path / "run"
    script = tmp_path / "fault.py"
    script.write_text(FAULT)
    argv = [*RUN, "--method", "adam", "--checkpoint-every", "4", "--out", str(out)]
    (code0, err0), (code1, _) = _two_ranks(argv, script=[str(script), "exit", "1", "6"])
    assert (code0, code1) == (1, 9)
    lines = [ln for ln in said(err0) if ln.startswith("pdeinv train")]
    assert len(lines) == 1 and "--resume" in lines[0] and "2-process run stopped" in lines[0], err0[-2000:]
    assert not (out / "metrics.json").exists()
    # the checkpoint after step 4 is there; one process resumes it (same global batch)
    assert main([*argv, "--resume"]) == 0
    _single(tmp_path / "whole", "--method", "adam")
    resumed = json.loads((out / "metrics.json").read_text())
    whole = json.loads((tmp_path / "whole" / "metrics.json").read_text())
    assert resumed["steps"] == 12
    assert resumed["x_err"] == pytest.approx(whole["x_err"], rel=1e-5)


def test_a_nan_on_one_rank_is_rejected_by_all_and_the_run_goes_on(tmp_path):
    out = tmp_path / "run"
    script = tmp_path / "fault.py"
    script.write_text(FAULT)
    (code0, err0), (code1, err1) = _two_ranks([*RUN, "--method", "adam", "--out", str(out)],
                                              script=[str(script), "nan", "1", "5"])
    assert (code0, code1) == (0, 0), err0[-2000:] + err1[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 12 and metrics["rejected_steps"] == 1 and metrics["world_size"] == 2
    assert "step 5 (adam)" in err0 and "rolled back" in err0 and err1.strip() == ""
    assert math.isfinite(metrics["x_err"])


def test_ranks_with_different_command_lines_are_refused(tmp_path):
    out = tmp_path / "run"
    argv = [*RUN, "--method", "gd", "--out", str(out)]
    other = [a if a != "3" else "4" for a in argv]  # --seed 3 on rank 0, --seed 4 on rank 1
    (code0, err0), (code1, err1) = _two_ranks(argv, other)
    assert (code0, code1) == (2, 2)
    lines = [ln for ln in err0.splitlines() if ln.strip()]
    assert len(lines) == 1 and "seed is 3 on rank 0 but 4 on rank 1" in lines[0], err0
    assert err1.strip() == ""  # rank 0 speaks for all
    assert _nothing_in(out)


class _TwoOfTwo(DataParallel):
    """Rank 0 of 2 without a process group: for refusals that happen before any collective."""

    def check_same(self, what, identity):
        pass


@pytest.mark.parametrize("extra, says", [
    (["--method", "gd", "--batch-size", "5"], "batch_size=5 does not split over 2 processes"),
    (["--method", "gd", "--batch-size", "1"], "batch_size=1 does not split over 2 processes"),
    (["--method", "hig", "--batch-size", "2"], "rule 'hig' cannot run on several processes with MLP"),
])
def test_bad_parallel_input_is_one_line_exit_2_nothing_written(tmp_path, monkeypatch, capsys, extra, says):
    monkeypatch.setattr(distributed, "from_env", lambda device: _TwoOfTwo(2, 0))
    out = tmp_path / "run"
    flags = {a for a in extra if a.startswith("--") and a != "--set"}  # the base gives way
    base = [a for i, a in enumerate(RUN) if a not in flags and (i == 0 or RUN[i - 1] not in flags)]
    assert main([*base, *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert _nothing_in(out)


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a machine without CUDA")
@pytest.mark.parametrize("device, says", [("cuda", "CUDA is not available"), ("tpu", "not a torch device"),
                                          ("mps", "not supported")])
def test_unavailable_device_is_one_line_exit_2_nothing_written(tmp_path, capsys, device, says):
    out = tmp_path / "run"
    assert main([*RUN, "--device", device, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0] and repr(device) in err[0], err
    assert _nothing_in(out)


def test_shards_are_equal_rows_in_rank_order():
    batch = torch.arange(12.0).reshape(6, 2)
    shards = [DataParallel(3, r).shard(batch) for r in range(3)]
    assert torch.equal(torch.cat(shards), batch)
    assert [len(s) for s in shards] == [2, 2, 2]


class _Agreeing(Single):
    """One process that plays a rank told by the others to stop at step ``at``, and not the writer."""

    is_writer = False

    def __init__(self, at: int):
        self.at, self.calls = at, 0

    def agree(self, flag):
        self.calls += 1
        return flag or self.calls == self.at


def test_the_trainer_stops_when_the_ranks_agree_and_only_the_writer_saves(tmp_path, heat):
    ckpt = pdeinv.Checkpoint(tmp_path / "c.pt", every=1)
    r = pdeinv.train(heat, pdeinv.GD(), steps=10, n_train=16, n_test=4, batch_size=4, checkpoint=ckpt,
                     parallel=_Agreeing(3), prior=None)
    assert r.metrics["steps"] == 3 and r.metrics["stopped_by"] == "another process"
    assert "y_err" in r.history[-1]  # evaluated at the agreed stop
    assert not ckpt.exists()


def test_hig_runs_on_two_processes_only_on_its_kronecker_route():
    assert Single().rule(pdeinv.HIG()) is not None
    sharded = DataParallel(2, 1).rule(pdeinv.HIG())
    assert sharded.inner.route == "kronecker" and sharded.inner.sum_over is not None
    with pytest.raises(ValueError, match=r"HIG\(route='svd'\) cannot run on 2 processes"):
        DataParallel(2, 1).rule(pdeinv.HIG(route="svd"))


def test_two_processes_train_hig_as_one(tmp_path):
    """HIG's Kronecker step from the moments summed over the ranks equals the one-process step."""
    at = RUN.index("--hidden")
    run = RUN[:at] + RUN[at + 2:]  # the default network: linear in θ
    assert main([*run, "--method", "hig", "--out", str(tmp_path / "one")]) == 0
    ranks = _two_ranks([*run, "--method", "hig", "--out", str(tmp_path / "two")])
    assert [code for code, _ in ranks] == [0, 0], ranks[0][1][-2000:]
    _same_run(tmp_path / "one", tmp_path / "two")


def test_single_process_strategy_changes_nothing():
    s = Single()
    rule = object()
    assert s.rule(rule) is rule and s.agree(True) and not s.agree(False) and s.is_writer
    assert s.world_size == 1 and math.isfinite(distributed.timeout_s())


def test_from_env_refuses_one_gpu_for_all_ranks_and_a_bad_world_size(monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")
    with pytest.raises(ValueError, match="puts all 2 processes on one GPU"):
        distributed.from_env(torch.device("cuda", 1))
    monkeypatch.setenv("WORLD_SIZE", "two")
    with pytest.raises(ValueError, match="WORLD_SIZE='two'"):
        distributed.from_env(torch.device("cpu"))
    monkeypatch.setenv("WORLD_SIZE", "1")
    assert isinstance(distributed.from_env(torch.device("cpu")), Single)


def test_the_sharded_rule_declares_what_its_rule_declares():
    """The data-parallel wrapper is a Rule that passes on its rule's declarations and carries the
    checkpoint protocol itself, not through ``__getattr__`` (which static lookups ignore: issue 24's
    latent bug); a rule of the minimal protocol declares no data-parallel form and is refused."""
    import inspect

    from pdeinv.methods.base import Rule
    from pdeinv.methods.protocol import declared

    sharded = DataParallel(2, 0).rule(pdeinv.GD())
    assert isinstance(sharded, Rule) and sharded.resumable and sharded.accepts_target
    assert sharded.name == "gd"

    class Minimal:
        name, transform = "mine", pdeinv.GD().transform

        def init(self, problem, model): ...

        def update(self, state, model, y): ...

    with pytest.raises(ValueError, match="'mine' cannot run on 2 processes: it declares no data-parallel"):
        DataParallel(2, 0).rule(declared(Minimal()))
    for name in ("state_dict", "load_state_dict", "hyperparameters"):
        assert callable(inspect.getattr_static(sharded, name))
    assert sharded.hyperparameters() == pdeinv.GD().hyperparameters()
