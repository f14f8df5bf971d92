"""SIGKILL a training run again and again -- at random moments and in the middle of a checkpoint
save -- and resume it: the checkpoint always loads, never goes back, and the finished run has
every step exactly once with the metrics of an uninterrupted run.

Budget: each subprocess pays ~3 s of imports (torch), so 5 kills + the final run take ~25 s.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pdeinv import Checkpoint
from pdeinv.cli import main

ROOT = Path(__file__).resolve().parents[1]
STEPS = 100
ARGS = ["train", "heat_1d", "--set", "n=16", "--set", "steps=10", "--hidden", "16", "--steps", str(STEPS),
        "--n-train", "64", "--n-test", "16", "--batch-size", "8", "--eval-every", "40", "--threads", "1",
        "--seed", "3"]


def _start(out: Path, resume: bool, every: int = 1) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    argv = [*ARGS, "--out", str(out), "--checkpoint-every", str(every), *(["--resume"] if resume else [])]
    return subprocess.Popen([sys.executable, "-m", "pdeinv.cli", *argv], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _temporaries(out: Path) -> set:
    if not out.is_dir():
        return set()
    return {n for n in os.listdir(out) if n.startswith(".checkpoint.pt.") and n.endswith(".tmp")}


def _inode(path: Path):
    try:
        return path.stat().st_ino  # os.replace gives every new checkpoint a new inode
    except FileNotFoundError:
        return None


def _wait_and_kill(proc, out: Path, stale: set, during_save: bool, rng) -> bool:
    """Kill ``proc`` once it is training: right as a new save's temporary appears (not one a
    killed predecessor left), or a random number of saves (steps) later plus a random few ms --
    counted in saves, not seconds, so a fast machine cannot finish the run first. False if it
    finished anyway."""
    deadline = time.monotonic() + 60
    ckpt = out / "checkpoint.pt"
    while not (ckpt.exists() and _temporaries(out) - stale):
        if proc.poll() is not None or time.monotonic() > deadline:
            return False
        time.sleep(0.0002)
    if not during_save:
        saves, last = rng.randint(1, 12), _inode(ckpt)
        while saves:
            if proc.poll() is not None or time.monotonic() > deadline:
                return False
            now = _inode(ckpt)
            saves -= now != last
            last = now
            time.sleep(0.0002)
        time.sleep(rng.uniform(0.0, 0.004))
    if proc.poll() is not None:
        return False
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return True


def test_sigkill_at_random_moments_and_during_saves_then_resume(tmp_path, capsys, one_thread):
    rng = random.Random(0)
    out = tmp_path / "run"
    saved_steps, kills, in_save = [], 0, 0
    for attempt in range(5):
        stale = _temporaries(out)
        proc = _start(out, resume=(out / "checkpoint.pt").exists())
        during_save = attempt % 2 == 1
        if not _wait_and_kill(proc, out, stale, during_save, rng):
            break
        kills += 1
        in_save += bool(_temporaries(out) - stale)  # a save's temporary was still there when it died
        saved = Checkpoint(out / "checkpoint.pt").load()  # always loads
        step = saved["position"]["step"]
        assert [h["step"] for h in saved["history"] if "rejected" not in h] == list(range(1, step + 1))
        assert not saved_steps or step >= saved_steps[-1]  # never goes back
        saved_steps.append(step)
        assert not (out / "metrics.json").exists()
    assert kills >= 4, f"only {kills} kills landed before the run finished"
    assert in_save >= 1, "no kill landed during a save"
    proc = _start(out, resume=True, every=STEPS)  # the rest in one go (--checkpoint-every may change)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr.decode()
    assert not _temporaries(out)  # the last save removed the temporaries the killed saves left

    # the same run, uninterrupted and without checkpoints
    assert main([*ARGS, "--out", str(tmp_path / "ref"), "--checkpoint-every", "0"]) == 0
    got = json.loads((out / "metrics.json").read_text())
    ref = json.loads((tmp_path / "ref" / "metrics.json").read_text())
    assert got["steps"] == ref["steps"] == STEPS
    for key in ("x_err", "y_err", "loss"):
        assert got[key] == pytest.approx(ref[key], rel=1e-10, abs=0)
    rows = (out / "history.csv").read_text().splitlines()
    ref_rows = (tmp_path / "ref" / "history.csv").read_text().splitlines()
    steps = [int(r.split(",")[0]) for r in rows[1:]]
    assert steps == list(range(1, STEPS + 1))  # every step exactly once: none lost, none repeated
    loss = rows[0].split(",").index("loss")
    for a, b in zip(rows[1:], ref_rows[1:]):
        assert float(a.split(",")[loss]) == pytest.approx(float(b.split(",")[loss]), rel=1e-10, abs=0)
    keys = ("x_err", "y_err", "loss")
    print(f"kills {kills} ({in_save} during a save), checkpoint steps {saved_steps}; "
          f"bitwise: {[got[k] for k in keys] == [ref[k] for k in keys]}")
