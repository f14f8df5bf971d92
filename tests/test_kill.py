"""SIGKILL a training run again and again -- right after an update, before it is saved, and in the
middle of a checkpoint save -- and resume it: the checkpoint always loads, never goes back, and the
finished run has every step exactly once with the metrics of an uninterrupted run.

The kills are deterministic: the run is started through ``tests/pausing.py``, which pauses at the
chosen point (the N-th update, or halfway through the N-th save's temporary) and writes a marker;
the test kills it when the marker appears, never after a guessed sleep.
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
from pdeinv.training.checkpoint import history_rows

ROOT = Path(__file__).resolve().parents[1]
STEPS = 100
ARGS = ["train", "--prior-fit", "0",
        "heat_1d", "--set", "n=16", "--set", "steps=10", "--hidden", "16", "--steps", str(STEPS),
        "--n-train", "64", "--n-test", "16", "--batch-size", "8", "--eval-every", "40", "--threads", "1",
        "--seed", "3"]


def _start(out: Path, resume: bool, every: int = 1, pause: str | None = None,
           marker: Path | None = None) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    argv = [*ARGS, "--out", str(out), "--checkpoint-every", str(every), *(["--resume"] if resume else [])]
    if pause is None:
        return subprocess.Popen([sys.executable, "-m", "pdeinv.cli", *argv], cwd=ROOT, env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    env.update(PDEINV_PAUSE=pause, PDEINV_MARKER=str(marker))
    return subprocess.Popen([sys.executable, str(ROOT / "tests" / "pausing.py"), *argv], cwd=ROOT,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _temporaries(out: Path) -> set:
    if not out.is_dir():
        return set()
    return {n for n in os.listdir(out) if n.startswith(".checkpoint.pt.") and n.endswith(".tmp")}


def _kill_when_paused(proc, marker: Path) -> None:
    """SIGKILL ``proc`` once it has paused (its marker exists); fail if it ends or hangs first."""
    deadline = time.monotonic() + 120
    while not marker.exists():
        assert proc.poll() is None, f"the run ended before pausing: {proc.communicate()[1].decode()}"
        assert time.monotonic() < deadline, "the run did not reach its pause point in 120 s"
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    marker.unlink()


@pytest.mark.slow
def test_sigkill_at_random_moments_and_during_saves_then_resume(tmp_path, capsys, one_thread):
    rng = random.Random(0)
    out, marker = tmp_path / "run", tmp_path / "paused"
    saved_steps, in_save = [], 0
    for attempt in range(5):
        stale = _temporaries(out)
        kind = "save" if attempt % 2 else "step"
        proc = _start(out, resume=(out / "checkpoint.pt").exists(), pause=f"{kind}:{rng.randint(2, 12)}",
                      marker=marker)
        _kill_when_paused(proc, marker)
        in_save += bool(_temporaries(out) - stale)  # a save's temporary was still there when it died
        saved = Checkpoint(out / "checkpoint.pt").load()  # always loads
        step = saved["position"]["step"]
        steps = [h["step"] for h in history_rows(saved["history"]) if "rejected" not in h]
        assert steps == list(range(1, step + 1))
        assert not saved_steps or step > saved_steps[-1]  # never goes back, and each run got further
        saved_steps.append(step)
        assert not (out / "metrics.json").exists()
    assert in_save == 2, "every kill in a save leaves its half-written temporary, and only those do"
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
    print(f"kills 5 ({in_save} during a save), checkpoint steps {saved_steps}; "
          f"bitwise: {[got[k] for k in keys] == [ref[k] for k in keys]}")
