"""Run ``pdeinv`` (the CLI) paused at a chosen point, for the kill test: ``python tests/pausing.py ARGV…``.

``PDEINV_PAUSE=step:N`` pauses right after the N-th update of this process was applied (parameters
changed, that step not yet saved); ``save:N`` pauses in the N-th atomic write, after half of the new
file's bytes went into its temporary (the rest follows when the pause ends). Pausing writes
``PDEINV_MARKER`` and waits until the test deletes it (at most 600 s): the test kills or signals the
process when the marker appears, so every kill lands exactly there, on any machine speed.
"""

import importlib
import io
import os
import sys
import time
from pathlib import Path

from pdeinv.cli import main

checkpoint = importlib.import_module("pdeinv.training.checkpoint")
guard = importlib.import_module("pdeinv.methods.guard")  # the Guard applies every update through it

KIND, N = os.environ["PDEINV_PAUSE"].split(":")
N = int(N)
MARKER = Path(os.environ["PDEINV_MARKER"])
calls = {"step": 0, "save": 0}


def pause():
    MARKER.write_text(f"{KIND}:{N}")
    deadline = time.monotonic() + 600
    while MARKER.exists() and time.monotonic() < deadline:
        time.sleep(0.01)


def counted(kind):
    calls[kind] += 1
    return KIND == kind and calls[kind] == N


real_step, real_write = guard.apply_if_finite, checkpoint.atomic_write


def apply_if_finite(*args, **kw):
    out = real_step(*args, **kw)
    if counted("step"):
        pause()
    return out


def atomic_write(path, write):
    if not counted("save"):
        return real_write(path, write)

    def half(fh):
        buf = io.BytesIO()
        write(buf)
        data = buf.getvalue()
        fh.write(data[: len(data) // 2])
        fh.flush()
        os.fsync(fh.fileno())
        pause()
        fh.write(data[len(data) // 2:])

    return real_write(path, half)


guard.apply_if_finite, checkpoint.atomic_write = apply_if_finite, atomic_write
sys.exit(main(sys.argv[1:]))
