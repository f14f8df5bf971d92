"""The ``--out`` folder of ``pdeinv train`` while it trains: a previous run's files replaced only once
this run writes (``--overwrite``), and ``history.csv`` grown with every checkpoint
(:class:`pdeinv.util.files.CsvLog`: the new rows appended).

What the folder holds when the run ends is :mod:`pdeinv.io.runs`. No torch at import: the CLI imports
every module of :mod:`pdeinv.cli.commands` to build its parser.
"""

from __future__ import annotations


class Fresh:
    """Called just before this run writes its first file: marks the folder as a pdeinv run
    (:func:`pdeinv.util.outpaths.mark_run_folder`, what lets a later ``--overwrite`` replace it) and, with
    ``--overwrite``, deletes the previous run's files once, so a run refused while setting up (a bad
    setting, a memory estimate) leaves them intact and one that trained never leaves a mix of two runs."""

    def __init__(self, out, enabled: bool):
        self.out, self.pending, self.marked = out, enabled, False

    def __call__(self) -> None:
        if self.pending:
            from pdeinv.io.runs import clear_outputs

            clear_outputs(self.out)
            self.pending = False
        if not self.marked:
            from pdeinv.util.outpaths import mark_run_folder

            mark_run_folder(self.out)
            self.marked = True


class FolderCheckpoint:
    """The run folder's :class:`~pdeinv.training.checkpoint.Checkpoint` (its ``path``, ``every``, ``exists``,
    ``load``), whose ``save`` calls ``fresh()`` first and writes ``history.csv`` beside it after (the
    history grows with the run, not only at its end)."""

    def __init__(self, path, every: int, fresh):
        from pdeinv.training.checkpoint import Checkpoint
        from pdeinv.util.files import CsvLog

        self.checkpoint, self.fresh = Checkpoint(path, every), fresh
        self.overwrite = True  # the run folder's policy decided that (pdeinv.util.outpaths.run_folder)
        self.path, self.every = self.checkpoint.path, self.checkpoint.every
        self.log = CsvLog(self.path.parent / "history.csv")

    def exists(self) -> bool:
        return self.checkpoint.exists()

    def load(self) -> dict:
        return self.checkpoint.load()

    def save(self, payload: dict) -> None:
        from pdeinv.training.checkpoint import history_length, history_rows

        self.fresh()
        self.checkpoint.save(payload)
        history = payload.get("history") or []
        if n := history_length(history):
            self.log.write(n, lambda start: history_rows(history, start))
