"""A training run's progress bar: tqdm on an interactive terminal, silent otherwise."""

from __future__ import annotations

import os
import sys


def progress(total: int | None, enabled: bool | None, initial: int = 0):
    """tqdm on an interactive terminal; silent when not a TTY, under CI (``CI`` set), or if disabled
    (``enabled=None``: decide from the terminal)."""
    from tqdm.auto import tqdm

    if enabled is None:
        enabled = sys.stderr.isatty() and not os.environ.get("CI")
    return tqdm(total=total, initial=initial, disable=not enabled, unit="step", leave=False)
