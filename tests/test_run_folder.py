"""Consistent run folders: ``--overwrite`` clears the previous run's files (only pdeinv's), conflicting
flags are refused, outputs respect the umask, a full disk during a checkpoint leaves the previous one
intact and says so in one line."""

from __future__ import annotations

import errno
import json
import os
import re
import stat
from pathlib import Path

import pytest
from stderr import said

from pdeinv import Checkpoint
from pdeinv.cli import main
from pdeinv.util.outpaths import RUN_MARKER

FAULTS = str(Path(__file__).with_name("faults.py"))
SMALL = ["--set", "n=16", "--n-train", "32", "--n-test", "16", "--batch-size", "8",
         "--hidden", "16", "--threads", "1"]


pytestmark = pytest.mark.usefixtures("one_thread")  # small dense work: one torch thread


def train(out, *extra, problem="heat_1d", steps=4):
    return main(["train", "--prior-fit", "0",
                 problem, *SMALL, "--steps", str(steps), "--out", str(out), *extra])


def one_line(capsys, head):
    err = said(capsys.readouterr().err)  # the plan and progress lines of a run that started aside
    assert len(err) == 1 and err[0].startswith(head) and "Traceback" not in err[0], err
    return err[0]


def test_overwrite_clears_the_previous_runs_files_and_only_those(tmp_path, capsys):
    out = tmp_path / "run"
    assert train(out, "--export-samples", "2") == 0
    assert {"fields.vtu", "fields.png", "checkpoint.pt"} <= {p.name for p in out.iterdir()}
    (out / "notes.txt").write_text("mine")
    assert train(out, "--export-samples", "0", "--checkpoint-every", "0", "--overwrite") == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"metrics.json", "history.csv", "training.png", "model.pt", "run.json", "posterior.npz",
                     "notes.txt", RUN_MARKER}
    capsys.readouterr()


def test_a_picture_alone_is_no_run_and_is_not_replaced(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "fields.vtu").write_text("stale")
    for extra in ([], ["--overwrite"]):  # a file with a run's name in an unmarked folder is the user's
        assert train(out, *extra) == 2
        assert "holds fields.vtu and is not a pdeinv run folder" in one_line(capsys, "pdeinv train: error: ")
    assert (out / "fields.vtu").read_text() == "stale"


def test_a_failed_overwrite_run_never_names_the_old_checkpoint(tmp_path, capsys):
    out = tmp_path / "run"
    assert train(out, "--checkpoint-every", "1", "--export-samples", "0") == 0
    capsys.readouterr()
    code = train(out, "--set", "poison=1,2,3", "--max-failures", "3", "--overwrite", problem=FAULTS)
    err = capsys.readouterr().err.splitlines()[-1]
    assert code == 1 and "no checkpoint was written yet" in err and "last good checkpoint" not in err
    assert not (out / "checkpoint.pt").exists() and not (out / "metrics.json").exists()
    assert not (out / "model.pt").exists() and "rejected" in (out / "history.csv").read_text()


def test_resume_with_overwrite_is_refused(tmp_path, capsys):
    assert train(tmp_path / "run", "--resume", "--overwrite") == 2
    assert "--resume and --overwrite conflict" in one_line(capsys, "pdeinv train: error: ")


def test_resume_with_fewer_steps_than_done_is_refused(tmp_path, capsys):
    out = tmp_path / "run"
    assert train(out, "--export-samples", "0", steps=6) == 0
    capsys.readouterr()
    before = (out / "metrics.json").read_bytes()
    assert train(out, "--resume", "--export-samples", "0", steps=3) == 2
    assert "6 steps done; steps=3 is below that" in one_line(capsys, "pdeinv train: error: ")
    assert (out / "metrics.json").read_bytes() == before
    assert train(out, "--resume", "--export-samples", "0", steps=8) == 0  # extending is fine
    assert json.loads((out / "metrics.json").read_text())["steps"] == 8


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_outputs_respect_the_umask(tmp_path, capsys, umask):
    old = os.umask(umask)
    try:
        assert train(tmp_path / "run", "--export-samples", "1") == 0
    finally:
        os.umask(old)
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in (tmp_path / "run").iterdir()}
    for name in ("metrics.json", "history.csv", "model.pt", "checkpoint.pt", "run.json"):
        assert modes[name] == 0o666 & ~umask, (name, oct(modes[name]))


def test_a_full_disk_during_a_checkpoint_keeps_the_previous_one(tmp_path, capsys, monkeypatch):
    import torch

    import pdeinv.training.checkpoint

    out, calls, real = tmp_path / "run", [], torch.save

    def save(obj, fh, *a, **kw):
        calls.append(1)
        if len(calls) == 3:  # the third checkpoint: half written, then the disk is full
            fh.write(b"x" * 100)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(obj, fh, *a, **kw)

    monkeypatch.setattr(pdeinv.training.checkpoint.torch, "save", save)
    code = train(out, "--checkpoint-every", "1", "--export-samples", "0", steps=5)
    line = one_line(capsys, "pdeinv train: cannot write: checkpoint ")
    assert code == 1 and "No space left on device" in line and "previous checkpoint is intact" in line
    assert "--resume" in line
    monkeypatch.setattr(pdeinv.training.checkpoint.torch, "save", real)
    assert Checkpoint(out / "checkpoint.pt").load()["position"]["step"] == 2
    assert not list(out.glob(".*.tmp"))


def test_history_grows_with_the_checkpoints_and_a_heartbeat_speaks_off_a_terminal(tmp_path, capsys):
    """history.csv is written with every checkpoint (not only at the end), and off a terminal the CLI's
    heartbeat prints a progress line every ``every_s`` seconds of training."""
    from pdeinv.cli.commands._folder import FolderCheckpoint
    from pdeinv.cli.commands.train import _Heartbeat

    ckpt = FolderCheckpoint(tmp_path / "checkpoint.pt", 1, lambda: None)
    ckpt.save({"history": [{"step": 1, "wall_s": 0.1, "loss": 0.5}], "model": {}})
    assert (tmp_path / "history.csv").read_text().splitlines() == ["step,wall_s,loss", "1,0.1,0.5"]
    from argparse import Namespace

    from pdeinv.cli.logs import cli_logging

    with cli_logging(Namespace()):  # the heartbeat speaks through logging at INFO (pdeinv.cli.logs)
        beat = _Heartbeat(steps=10, every_s=0.0)
        assert beat({"step": 3, "loss": 0.25, "wall_s": 61.0, "x_err": 0.125}, None) is False
        assert capsys.readouterr().err == ("pdeinv train: step 3/10, loss 0.25, x_err 0.125, 61 s, at most "
                                           "~142 s left in the rule's stage\n")  # 61 s / 3 steps x 7
        beat = _Heartbeat(steps=10)  # its first call speaks (a resumed run's first step is not 1)
        assert beat({"step": 4, "loss": 0.2, "wall_s": 1.0}, None) is False
        assert capsys.readouterr().err.startswith("pdeinv train: step 4/10, loss 0.2, 1 s")
        assert beat({"step": 5, "loss": 0.2, "wall_s": 1.2}, None) is False
        assert capsys.readouterr().err == ""  # within its minute: silent


@pytest.mark.parametrize("quiet", [False, True])
def test_the_prior_and_calibration_stages_say_what_they_do_unless_quiet(tmp_path, capsys, quiet):
    """A long stage is never mute: the prior stage says how long its draws will take at the pilot draws'
    pace and how many prior pairs it draws, then about ten
    lines of its fit with the steps done, the held-out error and the seconds left; the calibration
    stage says what it draws. ``-q`` silences them all; the result line stays."""
    args = ["train", "heat_1d", "--set", "n=16", "--set", "noise=0.01", "--steps", "3", "--prior-fit", "40",
            "--out", str(tmp_path / "r"), *(["-q"] if quiet else [])]
    assert main(args) == 0
    err = capsys.readouterr()
    said = [line for line in err.err.splitlines() if "stage" in line or "prior fit" in line]
    if quiet:
        assert said == [] and "heat_1d sip" in err.out + err.err
        return
    assert re.fullmatch(r"pdeinv train: prior stage: 64 pilot draws took \S+ s: the stage's 65536 draws will "
                        r"take at most ~\d+ s \(large batches go faster\), then the fit", said[0]), said[0]
    assert said[1] == "pdeinv train: prior stage: drawing 65536 prior pairs (x, y = P x)"
    assert "fitting the correction for at most 40 steps" in said[2]
    fits = [line for line in said if line.startswith("pdeinv train: prior fit step ")]
    assert 2 <= len(fits) <= 12
    assert fits[-1].startswith("pdeinv train: prior fit step 40/40: held-out x-error")
    assert said[-1] == "pdeinv train: calibration stage: drawing 4096 held-out prior pairs"
