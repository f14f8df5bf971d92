"""A signal during a checkpoint write (issue 48, item 3): SIGTERM inside one of the writes torch's C++
serializer makes came out as ``RuntimeError: [enforce fail at inline_container.cc:672]`` and exit 1. It is
held back until the file is in place (:mod:`pdeinv.util.critical`): exit 143, the usual one line, the
checkpoint whole (it loads and resumes) and no temporary left."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from pdeinv import Checkpoint
from pdeinv.cli import main
from pdeinv.cli.signals import TERMINATED, Terminated, terminate_as_interrupt
from pdeinv.util.files import atomic_write

ROOT = Path(__file__).resolve().parents[1]
ARGS = ["train", "heat_1d", "--set", "n=16", "--set", "steps=10", "--method", "gd", "--steps", "20",
        "--prior-fit", "0", "-q", "--n-train", "32", "--n-test", "8", "--checkpoint-every", "1",
        "--export-samples", "0", "--threads", "1"]

#: ``pdeinv train`` whose first checkpoint write sends SIGTERM to itself from inside a write torch's C++
#: writer makes (the third ``write`` of ``torch.save``'s file)
SCRIPT = """
import os, signal, sys
import torch

real_save = torch.save


class Writer:
    def __init__(self, fh):
        self.fh, self.calls = fh, 0

    def write(self, data):
        self.calls += 1
        if self.calls == 3:
            os.kill(os.getpid(), signal.SIGTERM)
        return self.fh.write(data)

    def flush(self):
        self.fh.flush()


def save(obj, f, *args, **kwargs):
    return real_save(obj, Writer(f) if hasattr(f, "fileno") else f, *args, **kwargs)


torch.save = save
from pdeinv.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_sigterm_inside_torchs_writer_waits_for_the_write(tmp_path):
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", SCRIPT, *ARGS, "--out", str(out)], cwd=tmp_path,
                          capture_output=True, env=env, timeout=120)
    err = done.stderr.decode()
    assert done.returncode == TERMINATED == 143, err
    assert "Traceback" not in err and "RuntimeError" not in err, err
    assert err.strip().splitlines() == [
        f"pdeinv train: terminated (SIGTERM); continue from {out / 'checkpoint.pt'} with --resume"], err
    assert Checkpoint(out / "checkpoint.pt").load()["position"]["step"] == 1  # the write it waited for
    assert not [n for n in os.listdir(out) if n.endswith(".tmp")]
    assert main([*ARGS, "--out", str(out), "--resume"]) == 0
    assert (out / "metrics.json").is_file()


def test_a_signal_during_an_atomic_write_is_raised_after_it(tmp_path):
    """In process: SIGTERM sent halfway through the bytes arrives as ``Terminated`` as the write ends, the
    file whole."""
    path = tmp_path / "f.bin"
    path.write_bytes(b"old")

    def write(fh):
        fh.write(b"new ")
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):  # bytecode boundaries where an unheld handler would raise
            pass
        fh.write(b"file")

    with terminate_as_interrupt(), pytest.raises(Terminated):
        atomic_write(path, write)  # raises as it returns, the file in place
    assert path.read_bytes() == b"new file"
    assert not [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]
