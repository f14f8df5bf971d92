"""SIGTERM is handled as Ctrl-C is (pdeinv.cli.signals): in the middle of a checkpoint save it waits for
the save (pdeinv.util.critical), names the checkpoint, exits 143, and the run resumes; Ctrl-C or SIGTERM
during start-up (imports, parsing, building the problem) exits 130 / 143 with at most one line and
no traceback (Ctrl-C at 0.6 s once crashed the interpreter re-importing a half-imported torch).

Deterministic where it matters: the save is paused by ``tests/pausing.py`` and signalled when its marker
appears; the start-up delays are spread over the imports on any machine speed.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from stderr import said

from pdeinv import Checkpoint
from pdeinv.cli.signals import INTERRUPTED, TERMINATED

ROOT = Path(__file__).resolve().parents[1]
ARGS = ["train", "--prior-fit", "0",
        "heat_1d", "--set", "n=16", "--set", "steps=10", "--hidden", "8", "--steps", "40",
        "--n-train", "16", "--n-test", "8", "--batch-size", "8", "--threads", "1", "--export-samples", "0"]


def _env(**extra):
    return {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", **extra}


@pytest.mark.parametrize("sig, code, says", [(signal.SIGTERM, TERMINATED, "terminated (SIGTERM)"),
                                             (signal.SIGHUP, 129, "hung up (SIGHUP)")],
                         ids=["SIGTERM", "SIGHUP"])
def test_sigterm_during_a_checkpoint_save_waits_for_it_and_resumes(tmp_path, sig, code, says):
    """SIGHUP (the terminal closed) is handled as SIGTERM: it died on the spot, no line, no last save."""
    out, marker = tmp_path / "run", tmp_path / "paused"
    env = _env(PDEINV_PAUSE="save:4", PDEINV_MARKER=str(marker))
    proc = subprocess.Popen([sys.executable, str(ROOT / "tests" / "pausing.py"), *ARGS, "--out", str(out),
                             "--checkpoint-every", "1"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env)
    deadline = time.monotonic() + 120
    while not marker.exists():
        assert proc.poll() is None, proc.communicate()[1].decode()
        assert time.monotonic() < deadline, "the run did not reach its pause point in 120 s"
        time.sleep(0.01)
    assert any(n.endswith(".tmp") for n in os.listdir(out))  # the half-written temporary is there
    proc.send_signal(sig)
    time.sleep(0.2)  # the signal is in, held back
    assert proc.poll() is None
    marker.unlink()  # the save goes on
    _, err = proc.communicate(timeout=60)
    err = err.decode()
    assert proc.returncode == code, err
    assert "Traceback" not in err and "nanobind" not in err and err.strip().splitlines()[-1] == (
        f"pdeinv train: {says}; continue from {out / 'checkpoint.pt'} with --resume"), err
    assert not [n for n in os.listdir(out) if n.endswith(".tmp")]  # in place, whole
    assert Checkpoint(out / "checkpoint.pt").load()["position"]["step"] == 4  # the save it waited for
    done = subprocess.run([sys.executable, "-m", "pdeinv", *ARGS, "--out", str(out), "--resume"],
                          cwd=tmp_path, capture_output=True, env=_env(), timeout=120)
    assert done.returncode == 0, done.stderr.decode()
    assert (out / "metrics.json").is_file()


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, INTERRUPTED), (signal.SIGTERM, TERMINATED)],
                         ids=["ctrl-c", "sigterm"])
def test_a_signal_during_start_up_exits_quietly(tmp_path, sig, code):
    """Signalled at moments spread over the start-up (the imports of torch and scipy take ~1-3 s)."""
    for delay in (0.3, 0.5, 0.6, 1.0):  # 0.5-0.6 s: inside the import of numpy, on this machine
        out = tmp_path / f"run_{delay}"  # one folder each: a run that finished first must not refuse the next
        proc = subprocess.Popen([sys.executable, "-m", "pdeinv", *ARGS, "--out", str(out)],
                                cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env())
        time.sleep(delay)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
        err = err.decode()
        assert proc.returncode in (code, 0), (delay, proc.returncode, err)  # 0: it finished first
        # at most one line of its own (the run's guard may already have warned on an idle machine)
        own = [line for line in said(err.strip()) if ": warning: " not in line]
        assert "Traceback" not in err and len(own) <= 1, (delay, err)


def test_a_signal_inside_a_finalizer_is_held_back_not_lost():
    """A signal arriving while a ``__del__`` runs is held back: raised there, Python would print
    "Exception ignored in" and go on (numpy's ``NpzFile.__del__`` once swallowed a SIGTERM so, and the
    run trained to its end); outside a finalizer or an import it is raised at once."""
    from pdeinv.cli.signals import _held_back

    seen = []

    class Finalized:
        def __del__(self):
            seen.append(_held_back(sys._getframe()))

    Finalized()
    assert seen == [True] and _held_back(sys._getframe()) is False
