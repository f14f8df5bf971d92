"""One run per output folder (:mod:`pdeinv.util.runlock`): a second run on a held folder is refused in one
line naming the folder and the holder's PID, writing nothing; a SIGKILLed holder never blocks the
next run; runs one after another are unaffected.

Holders are small subprocesses that load ``pdeinv/util/runlock.py`` by path (no torch import: ~50 ms).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from pdeinv.cli import main
from pdeinv.util import runlock
from pdeinv.util.runlock import NAME, FolderLocked, RunLock

MODULE = Path(runlock.__file__)
SMALL = ["--set", "n=16", "--set", "steps=10", "--hidden", "8", "--n-train", "16", "--n-test", "8",
         "--batch-size", "8", "--threads", "1", "--export-samples", "0"]

_HOLD = """
import importlib.util, sys, time
spec = importlib.util.spec_from_file_location("runlock", sys.argv[1])
runlock = importlib.util.module_from_spec(spec)
spec.loader.exec_module(runlock)
runlock.RunLock(sys.argv[2]).acquire()
print("held", flush=True)
time.sleep(120)
"""


def _holder(folder: Path) -> subprocess.Popen:
    """A process holding the lock on ``folder`` (until killed)."""
    proc = subprocess.Popen([sys.executable, "-c", _HOLD, str(MODULE), str(folder)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    assert line == "held\n", proc.stderr.read()
    return proc


def _kill(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    proc.stdout.close()
    proc.stderr.close()


def _snapshot(folder: Path) -> dict:
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished train run (metrics.json, checkpoint.pt, model.pt, ...) to copy."""
    run = tmp_path_factory.mktemp("lock") / "run"
    assert main(["train", "--prior-fit", "0", "heat_1d", *SMALL, "--steps", "2", "--checkpoint-every", "1",
                 "--out", str(run)]) == 0
    assert not (run / NAME).exists()  # a finished run leaves no lock file behind
    return run


@pytest.mark.parametrize(("argv", "why"), [
    (["train", "--prior-fit", "0", "heat_1d", *SMALL, "--steps", "2", "--overwrite"], "PID"),
    (["train", "--prior-fit", "0", "heat_1d", *SMALL, "--steps", "4", "--resume"], "PID"),
    # a sweep never writes into a run's folder, held or not (pdeinv.util.outpaths.output_folder's record)
    (["bench", "heat_1d", "--quick", "--set", "n=16"], "holds .pdeinv-run"),
    (["stress", "heat_1d", "--quick"], "holds .pdeinv-run"),
], ids=["train-overwrite", "train-resume", "bench", "stress"])
def test_a_second_run_on_a_held_folder_is_refused(finished, tmp_path, capsys, argv, why):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(finished, run)
    holder = _holder(run)
    try:
        before = _snapshot(run)
        assert before[Path(NAME)] == f"{holder.pid}\n".encode()
        code = main([*argv, "--out", str(run)])
        out, err = capsys.readouterr()
        assert code == 2, err
        assert err.count("\n") == 1 and err.startswith(f"pdeinv {argv[0]}: error: "), err
        assert "Traceback" not in err
        assert repr(str(run)) in err and (f"PID {holder.pid}" if why == "PID" else why) in err, err
        assert _snapshot(run) == before  # metrics, checkpoint, model and the holder's .lock: same bytes
    finally:
        _kill(holder)


def test_a_sigkilled_holder_does_not_block_resume(finished, tmp_path, capsys):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(finished, run)
    holder = _holder(run)
    with pytest.raises(FolderLocked, match=rf"PID {holder.pid}\b"):
        RunLock(run).acquire()
    _kill(holder)
    assert (run / NAME).read_text() == f"{holder.pid}\n"  # a stale lock file, its holder dead
    with RunLock(run) as lock:  # acquirable: the OS dropped the lock with the process
        assert (run / NAME).read_text() == f"{os.getpid()}\n"
    assert not lock.held and not (run / NAME).exists()
    holder = _holder(run)
    _kill(holder)
    assert (run / NAME).exists()
    assert main(["train", "--prior-fit", "0",
                 "heat_1d", *SMALL, "--steps", "4", "--checkpoint-every", "1", "--resume",
                 "--out", str(run)]) == 0, capsys.readouterr().err
    assert "4 steps" in capsys.readouterr().out
    assert not (run / NAME).exists()


def test_runs_one_after_another_on_one_folder(tmp_path, capsys):
    run = tmp_path / "run"
    base = ["train", "--prior-fit", "0", "heat_1d", *SMALL, "--checkpoint-every", "1", "--out", str(run)]
    assert main([*base, "--steps", "2"]) == 0
    assert main([*base, "--steps", "3", "--resume"]) == 0
    assert main([*base, "--steps", "2", "--overwrite"]) == 0
    capsys.readouterr()
    assert not (run / NAME).exists()
    for _ in range(3):  # the same object, and fresh ones, again and again
        with RunLock(run):
            pass
    lock = RunLock(run)
    lock.acquire()
    lock.release()
    lock.acquire()
    lock.release()
    assert not (run / NAME).exists()


def test_one_process_two_locks_and_the_message(tmp_path):
    """flock belongs to the open file: a second RunLock in the same process is refused too."""
    with RunLock(tmp_path):
        with pytest.raises(FolderLocked) as info:
            RunLock(tmp_path).acquire()
    assert info.value.pid == os.getpid() and info.value.folder == tmp_path
    assert str(info.value) == (f"{str(tmp_path)!r} is in use by another pdeinv run (PID {os.getpid()} "
                               "holds .lock); wait for it to end or choose another output folder")
    with RunLock(tmp_path):  # released on leaving the block, exceptions included
        pass
    with pytest.raises(KeyError), RunLock(tmp_path):
        raise KeyError("x")
    with RunLock(tmp_path):
        pass


def test_unreadable_pid_and_no_fcntl(tmp_path, monkeypatch):
    (tmp_path / NAME).write_text("")  # a holder that has not written its PID yet
    fd = os.open(tmp_path / NAME, os.O_RDONLY)
    try:
        import fcntl

        fcntl.flock(fd, fcntl.LOCK_EX)
        with pytest.raises(FolderLocked, match="PID unknown"):
            RunLock(tmp_path).acquire()
    finally:
        os.close(fd)
    assert (tmp_path / NAME).read_text() == ""  # the refused run wrote nothing
    monkeypatch.setattr(runlock, "fcntl", None)  # Windows: no lock, nothing written
    (tmp_path / NAME).unlink()
    with RunLock(tmp_path), RunLock(tmp_path):
        assert not (tmp_path / NAME).exists()


_CONTEND = """
import importlib.util, os, sys
spec = importlib.util.spec_from_file_location("runlock", sys.argv[1])
runlock = importlib.util.module_from_spec(spec)
spec.loader.exec_module(runlock)
folder, rounds, got = sys.argv[2], int(sys.argv[3]), 0
inside = os.path.join(folder, "inside")
while got < rounds:
    try:
        lock = runlock.RunLock(folder).acquire()
    except runlock.FolderLocked:
        continue
    os.close(os.open(inside, os.O_CREAT | os.O_EXCL | os.O_WRONLY))  # FileExistsError: two inside
    os.unlink(inside)
    lock.release()
    got += 1
print(got)
"""


def test_removing_the_lock_file_never_lets_two_in(tmp_path):
    """Holders remove .lock on release; contenders that locked a removed file must notice."""
    procs = [subprocess.Popen([sys.executable, "-c", _CONTEND, str(MODULE), str(tmp_path), "300"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(4)]
    for p in procs:
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0 and out.strip() == "300", err
    assert not (tmp_path / NAME).exists() and not (tmp_path / "inside").exists()
