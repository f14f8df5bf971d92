"""Checkpoints of a training run: atomic files (:mod:`pdeinv.util.files`), and a refusal to resume a
different run.

Guarantees:

* **Atomic.** :meth:`Checkpoint.save` writes a temporary file in the checkpoint's
  own folder, flushes and ``fsync``\\ s it, ``os.replace``\\ s it over the target
  and ``fsync``\\ s the folder. A process killed at any moment (SIGKILL included)
  leaves the previous checkpoint or the new one, never a mix or a partial file;
  after the folder's ``fsync`` the new one also survives a power loss. A save
  that fails (a full disk) raises ``OSError`` saying so and leaves the previous
  checkpoint intact. SIGTERM and Ctrl-C during a save wait for it (:mod:`pdeinv.util.critical`: inside
  torch's C++ writer they came out as ``RuntimeError: [enforce fail …]``). A
  temporary left behind by a killed save is removed by the next save.
* **Safe to load.** Files are read with ``torch.load(weights_only=True)``: a
  checkpoint can hold tensors, numbers, strings, lists and dicts, never code.
  Anything unreadable is reported as a corrupt checkpoint (``ValueError``).
* **Same run only.** A checkpoint records an *identity* — problem name and
  settings, network class, parameter shapes and architecture (every submodule's
  class and scalar settings: layer widths, activations, whitening floor, …),
  update rule and every one of its hyper-parameters (``rule.hyperparameters()``:
  optimizer and lr, η, τ, routes, …, as configured), and the trainer's data
  settings (seed, n_train, n_test, batch_size, dtype). :func:`check_identity`
  refuses to resume when any of them differs, naming the key and both values.
  The step count and time budget are not part of it: a run may be extended.

A run's checkpoint (:class:`pdeinv.Trainer`) holds ``identity`` (:func:`run_identity`), ``model``
(its state dict), ``rule_state`` (``rule.state_dict``), ``position`` (batch order and its position,
step, wall time, what stopped the run), ``guard`` (:meth:`pdeinv.methods.guard.Guard.state_dict`:
step-size multiplier, failures, lowest loss, last good state), ``rng`` (:func:`rng_states`) and
``history``; :func:`load_to_resume` loads one and refuses what this run cannot continue.
"""

from __future__ import annotations

import os
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
import torch

from .._checks import count, flag
from ..util.files import atomic_write, plain, remove_stale_temporaries, same_row

__all__ = ["Checkpoint", "check_identity", "network_identity", "load_to_resume", "Position",
           "check_resumable", "restore", "rng_states", "save", "run_identity", "set_rng_states"]

FORMAT = "pdeinv-checkpoint"
VERSION = 2  # 2: rule state = transformation + steps; identity with hyper-parameters


@runtime_checkable
class Checkpointing(Protocol):
    """What the trainer asks of a checkpoint: ``save``, ``load`` and ``exists``, its ``path`` (named in
    messages), and ``overwrite``: whether a run that does not resume may replace the checkpoint it finds
    there."""

    path: os.PathLike
    overwrite: bool

    def save(self, *args, **kwargs): ...

    def load(self, *args, **kwargs): ...

    def exists(self) -> bool: ...


@dataclass
class Checkpoint:
    """Where a run is checkpointed and how often: every ``every`` steps and after the last.

    ``Trainer(..., checkpoint=Checkpoint("run/checkpoint.pt", every=50), resume=True)``
    continues from ``run/checkpoint.pt`` if it exists. A run that does not resume refuses an existing
    checkpoint there unless ``overwrite`` (it would replace another run's).
    """

    path: str | os.PathLike
    every: int = 100
    overwrite: bool = False

    def __post_init__(self):
        """Creates the folder and proves it writable now, so a bad path fails before training
        (``ValueError`` naming it), not at the first save."""
        import tempfile

        if not isinstance(self.path, (str, os.PathLike)) or isinstance(os.fspath(self.path), bytes):
            raise TypeError(f"path={self.path!r:.60} is {type(self.path).__name__}; expected a path (str or "
                            "os.PathLike), e.g. Checkpoint('run/checkpoint.pt')")
        self.path = Path(self.path)
        self.every = count(self.every, "checkpoint every")
        flag(self.overwrite, "Checkpoint(overwrite)")
        folder = self.path.parent
        if folder.exists() and not folder.is_dir():
            raise ValueError(f"checkpoint {str(self.path)!r}: {str(folder)!r} is a file; "
                             "expected a directory")
        try:
            folder.mkdir(parents=True, exist_ok=True)
            tempfile.TemporaryFile(dir=folder).close()
        except OSError as err:
            raise ValueError(f"checkpoint {str(self.path)!r}: folder {str(folder)!r} is not a writable "
                             f"directory ({err.strerror or err}); choose another path") from None
        if self.path.is_dir():
            raise ValueError(f"checkpoint {str(self.path)!r} is a directory; expected a file path")
        if self.path.exists() and not self.path.is_file():
            raise ValueError(f"checkpoint {str(self.path)!r} is not a regular file; choose another path")
        if self.path.is_file():  # a user's file there was replaced by the first save, silently
            try:
                self.load()
            except ValueError:
                raise ValueError(f"checkpoint {str(self.path)!r} exists and is corrupt or not a pdeinv "
                                 "checkpoint: saving there would replace it; choose another path (or delete "
                                 "it, if it is a broken checkpoint)") from None

    def exists(self) -> bool:
        return self.path.is_file()

    def save(self, payload: dict) -> None:
        """Write ``payload`` atomically (see the module docstring)."""
        payload = {"format": FORMAT, "version": VERSION, **payload}
        remove_stale_temporaries(self.path)
        try:
            atomic_write(self.path, lambda fh: torch.save(payload, fh))
        except OSError as err:  # e.g. ENOSPC: the temporary is gone, the previous checkpoint intact
            kept = "the previous checkpoint is intact" if self.exists() else "no checkpoint was kept"
            raise OSError(err.errno, f"checkpoint {str(self.path)!r} not saved ({err.strerror or err}); "
                                     f"{kept}") from None

    def load(self) -> dict:
        """The saved payload; ``FileNotFoundError`` if there is none, ``ValueError`` if it is corrupt."""
        if not self.exists():
            raise FileNotFoundError(f"no checkpoint at {str(self.path)!r}")
        try:
            payload = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception as err:  # torch raises RuntimeError, UnpicklingError, EOFError, ... by format
            first = str(err).strip().splitlines()[0][:120] if str(err).strip() else type(err).__name__
            raise ValueError(f"checkpoint {str(self.path)!r} is corrupt or not a pdeinv checkpoint "
                             f"({first}); delete it to start over") from None
        if not isinstance(payload, dict) or payload.get("format") != FORMAT:
            raise ValueError(f"{str(self.path)!r} is not a pdeinv checkpoint; delete it to start over")
        if payload.get("version") != VERSION:
            raise ValueError(f"checkpoint {str(self.path)!r} has format version {payload.get('version')!r}; "
                             f"this pdeinv reads version {VERSION}")
        return payload


# -- identity: what must match to resume ---------------------------------------------------------

def network_identity(model: torch.nn.Module) -> dict:
    """Class, parameter/buffer shapes and architecture: ``{"<module>": class, "<module>.<setting>": value}``
    over every submodule, its settings being its public scalar attributes (``out_features``,
    ``rel_floor``, ``drop``, …; fitted values are buffers, not settings)."""
    arch = {}
    for name, module in model.named_modules():
        key = name or "<root>"
        arch[key] = type(module).__qualname__
        for attr, value in vars(module).items():
            if not attr.startswith("_") and attr != "training" and isinstance(value, (bool, int, float, str)):
                arch[f"{key}.{attr}"] = value
    return {"class": type(model).__qualname__,
            "shapes": {k: list(v.shape) for k, v in model.state_dict().items()}, "architecture": plain(arch)}


#: the most differences a refusal names (then "and N more"): a whole network's dump was 1–3 kB of one line
FEW = 4


def _few(items: list) -> str:
    """The first :data:`FEW` of ``items``, comma-separated, and how many more there are."""
    more = f", and {len(items) - FEW} more" if len(items) > FEW else ""
    return ", ".join(items[:FEW]) + more


def _describe_network(net: dict, other: dict) -> str:
    """``net``'s class and the parameter shapes in which it differs from ``other`` (at most :data:`FEW`)."""
    shapes, theirs = net["shapes"], other["shapes"]
    differ = [f"{k} {tuple(s)}" for k, s in shapes.items() if theirs.get(k) != s]
    return f"{net['class']} ({_few(differ) if differ else 'the same shapes'})"


def _differences(saved: dict, current: dict) -> str:
    """``key=saved (checkpoint) vs current (this run)`` for the keys whose values differ (at most
    :data:`FEW`, then how many more)."""
    keys = [k for k in dict.fromkeys([*saved, *current]) if saved.get(k) != current.get(k)]
    return _few([f"{k}={saved.get(k)!r} (checkpoint) vs {current.get(k)!r} (this run)" for k in keys])


#: the CLI's flags of the trainer's data settings (a refusal names both)
TRAINER_FLAGS = {"seed": "--seed", "n_train": "--n-train", "n_test": "--n-test", "batch_size": "--batch-size",
                 "data": "--data", "fresh": "--fresh-draws"}


def _data_value(key: str, value) -> str:
    """A data setting as the user gave it: the data file by its rows' fingerprint, or none."""
    if key == "data":
        return "none (the scene's draws)" if value is None else f"a file of fingerprint {value}"
    return repr(value)


def _same_rule(saved: str, current: str, where: str) -> None:
    if saved != current:
        raise ValueError(f"{where} was written with rule {saved!r}; this run has {current!r} "
                         "(resume with the same rule, the CLI's --method, or use another output folder)")


def _same_data(old: dict, new: dict, keys: list, where: str) -> None:
    """Refuse data settings ``keys`` that differ between the checkpoint's (``old``) and this run's."""
    if not keys:
        return
    said = _few([f"{k}={_data_value(k, old.get(k))} (checkpoint) vs {_data_value(k, new.get(k))} "
                 "(this run)" + (f" ({TRAINER_FLAGS[k]})" if k in TRAINER_FLAGS else "") for k in keys])
    raise ValueError(f"{where} was written with other data settings: {said}; resume with the same ones, "
                     "or use another output folder")


def check_problem(saved: dict, current: dict, path) -> None:
    """Refuse (``ValueError``) when the checkpoint at ``path`` is of another problem or other settings
    (``saved``, ``current``: identities with ``problem`` and ``settings``; ``pdeinv train --explain
    --resume`` checks this much before anything is built)."""
    where = f"checkpoint {str(path)!r}"
    if saved["problem"] != current["problem"]:
        raise ValueError(f"{where} is of problem {saved['problem']!r}, this run is {current['problem']!r}; "
                         "use another output folder or the same problem")
    diff = _differences(saved["settings"], current["settings"])
    if diff:
        raise ValueError(f"{where} is of problem {saved['problem']!r} with other settings: {diff}")


def check_identity(saved: dict, current: dict, path) -> None:
    """Refuse (``ValueError``) when the checkpoint at ``path`` belongs to a different run."""
    where = f"checkpoint {str(path)!r}"
    check_problem(saved, current, path)
    _same_rule(saved["rule"], current["rule"], where)  # before the network, which another rule changes too
    keys = [k for k in dict.fromkeys([*saved["trainer"], *current["trainer"]])
            if saved["trainer"].get(k) != current["trainer"].get(k)]
    if keys and set(keys) != {"dtype"}:  # a data file builds its own network, n_train sizes it: said first
        _same_data(saved["trainer"], current["trainer"], ["data"] if "data" in keys else keys, where)
    _same_network(saved["network"], current["network"], where)  # the dtype follows the network (--hidden)
    if keys:
        _same_data(saved["trainer"], current["trainer"], keys, where)
    diff = _differences(saved["hyperparameters"], current["hyperparameters"])
    if diff:
        raise ValueError(f"{where} was written with rule {saved['rule']!r} and other hyper-parameters: "
                         f"{diff}; resume with the same settings (only --steps / --time-budget may change)")


def _same_network(s_net: dict, c_net: dict, where: str) -> None:
    """Refuse a checkpoint of another network, naming what differs."""
    if s_net.get("class") != c_net.get("class"):  # another kind of network: its parts say nothing more
        raise ValueError(f"{where} holds a {s_net.get('class')} network; this run's is a "
                         f"{c_net.get('class')} (another --net, --hidden or data file?): resume with the "
                         "same ones, or use another output folder")
    if s_net != c_net:
        diff = _differences(s_net.get("architecture", {}), c_net.get("architecture", {}))
        raise ValueError(f"{where} holds network {_describe_network(s_net, c_net)}; this run's network is "
                         f"{_describe_network(c_net, s_net)}" + (f": {diff}" if diff else ""))


def run_identity(problem, rule, model: torch.nn.Module, trainer: dict) -> dict:
    """What a checkpoint must share with a run to be resumed by it: the problem and its settings, the
    network, the rule and its *configured* hyper-parameters (the guard's lowered step size is run state,
    not identity), and the trainer's data settings ``trainer``."""
    return {"problem": problem.name, "settings": plain(problem.settings),
            "network": network_identity(model), "rule": rule.name,
            "hyperparameters": plain(rule.hyperparameters()), "trainer": trainer}


#: what every checkpoint a Trainer writes holds (module docstring)
REQUIRED = ("identity", "model", "rule_state", "position", "rng", "history")


def _saved(ckpt: Checkpoint) -> dict:
    """What ``ckpt`` holds: ``FileNotFoundError`` when there is none, ``ValueError`` when it was not
    written by a trainer."""
    if not ckpt.exists():
        raise FileNotFoundError(f"resume: there is no checkpoint at {str(ckpt.path)!r} to resume from "
                                "(start without resume / --resume)")
    saved = ckpt.load()
    missing = sorted(set(REQUIRED) - set(saved))
    if missing:
        raise ValueError(f"checkpoint {str(ckpt.path)!r} lacks {', '.join(missing)}: not written by "
                         "pdeinv.Trainer; delete it to start over")
    return saved


def resumable_for(ckpt: Checkpoint, problem, rule: str | None = None, steps: int | None = None,
                  trainer: dict | None = None) -> None:
    """Refuse resuming ``ckpt`` before anything is built (``pdeinv train --explain --resume``): no
    checkpoint, not a trainer's, of another problem or settings, another ``rule`` (its name), fewer
    ``steps`` than it has done, or other ``trainer`` data settings among those given (``seed``, …); the
    network and the rule's hyper-parameters are compared when the run starts."""
    saved = _saved(ckpt)
    identity = saved["identity"]
    check_problem(identity, {"problem": problem.name, "settings": plain(problem.settings)}, ckpt.path)
    where = f"checkpoint {str(ckpt.path)!r}"
    if rule is not None:
        _same_rule(identity["rule"], rule, where)
    old = identity.get("trainer", {})
    _same_data(old, trainer or {}, [k for k, v in (trainer or {}).items() if k in old and old[k] != v], where)
    done = saved["position"]["step"]
    if steps is not None and steps < done:
        raise ValueError(f"resume: {where} has {done} steps done; steps={steps} is below that (give "
                         f"steps >= {done} to extend the run, or start over)")


def load_to_resume(ckpt: Checkpoint, identity: dict, steps: int | None) -> dict:
    """The payload of ``ckpt`` for a run of ``identity`` going to ``steps`` (None: no step limit).

    ``FileNotFoundError`` when there is none; ``ValueError`` when it was not written by a trainer,
    belongs to another run (:func:`check_identity`) or has more steps done than ``steps``."""
    saved = _saved(ckpt)
    check_identity(saved["identity"], identity, ckpt.path)
    done = saved["position"]["step"]
    if steps is not None and steps < done:
        raise ValueError(f"resume: checkpoint {str(ckpt.path)!r} has {done} steps done; "
                         f"steps={steps} is below that (give steps >= {done} to extend the run, "
                         "or start over)")
    return saved


@dataclass
class Position:
    """Where a run is: everything besides the model, the rule state and the guard that a resumed run
    must restore (the checkpoint's ``position``), and the batch order it draws from."""

    gen: torch.Generator  # batch order
    order: torch.Tensor
    pos: int = 0
    step: int = 0  # accepted steps
    wall: float = 0.0
    stopped_by: str | None = None  # a stopping rule or callback that ended the run
    y_err0: float | None = None  # the test y-error of the network training started from (.evaluation)

    def saved(self) -> dict:
        return {"gen": self.gen.get_state(), "order": self.order, "pos": self.pos, "step": self.step,
                "wall": self.wall, "stopped_by": self.stopped_by, "y_err0": self.y_err0}

    def restore(self, p: dict) -> None:
        self.gen.set_state(p["gen"])
        self.order, self.pos, self.step, self.wall = p["order"], p["pos"], p["step"], p["wall"]
        self.stopped_by, self.y_err0 = p.get("stopped_by"), p.get("y_err0")

    def next_rows(self, size: int, n: int) -> torch.Tensor:
        """The next ``size`` of ``n`` row indices: without replacement, reshuffled every epoch."""
        if self.pos + size > n:
            self.order, self.pos = torch.randperm(n, generator=self.gen), 0
        rows = self.order[self.pos:self.pos + size]
        self.pos += size
        return rows


def check_resumable(rule) -> None:
    """Refuse (``ValueError``) a rule (declared, :mod:`pdeinv.methods.protocol`) whose run cannot be
    checkpointed."""
    if not rule.resumable:
        raise ValueError(f"rule {rule.name!r} cannot be checkpointed: it does not declare resumable = True "
                         "with state_dict / load_state_dict / hyperparameters (derive it from "
                         "pdeinv.methods.base.Rule; see pdeinv.methods.base.Resumable)")


#: the tensor type of a history column whose values are all of one of these Python types
_COLUMN_TYPES = {float: torch.float64, int: torch.int64, bool: torch.bool}


class HistoryColumns:
    """A run's history (rows of numbers and strings) as columns, ``{"rows": n, "columns": {key: (row
    indices, values)}}``, the values a tensor where a key's values are all floats, all ints or all bools
    (the step, the loss, the errors: saved as raw bytes) and a list otherwise (a rejected step's
    message); :func:`history_rows` gives back the rows. Called again on the grown history, it reads only
    the rows new since the last call (a changed last row, or a history that is no longer an extension,
    starts over): saving a history as one dict per row cost ~18 µs a row at every save, so a 20 000-step
    run saved every 50 steps spent most of its time in its checkpoints."""

    def __init__(self):
        self.at: dict[str, list[int]] = {}
        self.values: dict[str, list] = {}
        self.n, self.last = 0, None

    def __call__(self, rows: list[dict]) -> dict:
        if not (0 < self.n <= len(rows) and same_row(rows[self.n - 1], self.last)):
            self.__init__()
        for i in range(self.n, len(rows)):
            for key, value in rows[i].items():
                self.at.setdefault(key, []).append(i)
                self.values.setdefault(key, []).append(value)
        self.n, self.last = len(rows), dict(rows[-1]) if rows else None
        columns = {}
        for key, vals in self.values.items():
            kinds = {type(v) for v in vals}
            kind = _COLUMN_TYPES.get(kinds.pop()) if len(kinds) == 1 else None
            columns[key] = (torch.tensor(self.at[key], dtype=torch.int64),
                            torch.tensor(vals, dtype=kind) if kind is not None else plain(vals))
        return {"rows": self.n, "columns": columns}


def history_columns(rows: list[dict]) -> dict:
    """``rows`` as columns (:class:`HistoryColumns`, at once)."""
    return HistoryColumns()(rows)


def history_length(saved) -> int:
    """The number of rows of a saved history (:func:`history_rows`)."""
    return len(saved) if isinstance(saved, list) else int(saved["rows"])


def history_rows(saved, start: int = 0) -> list[dict]:
    """Rows ``start:`` of what :class:`HistoryColumns` was given (dicts, each row's keys in the columns'
    order; only those rows are read); a history saved as a list of rows is sliced."""
    if isinstance(saved, list):
        return saved if start == 0 else saved[start:]
    try:
        rows: list[dict] = [{} for _ in range(max(int(saved["rows"]) - start, 0))]
        for key, (at, vals) in saved["columns"].items():
            first = int(torch.searchsorted(at, start)) if start else 0
            kept = vals[first:]
            for i, v in zip(at[first:].tolist(), kept.tolist() if isinstance(kept, torch.Tensor) else kept,
                            strict=True):
                rows[i - start][key] = v
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, RuntimeError):
        raise ValueError("the checkpoint's history is not a pdeinv run's history; delete the checkpoint "
                         "to start over") from None
    return rows


def save(ckpt: Checkpoint, identity: dict, model: torch.nn.Module, rule, state, at: Position, guard,
         history: list, columns: HistoryColumns | None = None) -> None:
    """Save a run (module docstring) atomically to ``ckpt``, its history as columns (``columns``, the
    run's :class:`HistoryColumns`, reads only the rows new since its last save)."""
    ckpt.save({"identity": identity, "model": model.state_dict(), "rule_state": rule.state_dict(state),
               "position": at.saved(), "guard": guard.state_dict(), "rng": rng_states(),
               "history": (columns or HistoryColumns())(history)})


def restore(saved: dict, model: torch.nn.Module, rule, state, at: Position, guard):
    """Put a payload of :func:`load_to_resume` back: the model's parameters (copied into the same
    Parameters the optimizer holds), the rule state (returned), the position, the guard, the global
    generators."""
    model.load_state_dict(saved["model"])
    state = rule.load_state_dict(state, saved["rule_state"])
    at.restore(saved["position"])
    guard.load_state_dict(saved.get("guard") or {**saved["position"], "good": saved.get("good")})
    set_rng_states(saved["rng"])
    return state


def last_good(good_step: int | None, ckpt: Checkpoint | None, saved_step: int | None) -> str:
    """Where a stopped run left its state: the last good state the model holds (after step
    ``good_step``), and the last checkpoint *this* run wrote (at ``saved_step``)."""
    state = "no step was verified" if good_step is None else \
        f"the model holds the last good state (after step {good_step})"
    if ckpt is None:
        return f"{state}; checkpointing is off, nothing was saved"
    if saved_step is None:
        return f"{state}; no checkpoint was written yet ({str(ckpt.path)!r})"
    return f"{state}; last good checkpoint: {str(ckpt.path)!r} (step {saved_step})"


# -- random number generators -------------------------------------------------------------------

def rng_states() -> dict:
    """torch's, numpy's and Python's global generator states (torch.load(weights_only)-safe)."""
    name, key, pos, has_gauss, gauss = np.random.get_state()
    return {"torch": torch.get_rng_state(),
            "numpy": {"name": name, "key": torch.from_numpy(key.astype(np.int64)), "pos": int(pos),
                      "has_gauss": int(has_gauss), "gauss": float(gauss)},
            "python": random.getstate()}


def set_rng_states(states: dict) -> None:
    torch.set_rng_state(states["torch"])
    n = states["numpy"]
    np.random.set_state((n["name"], n["key"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["gauss"]))
    version, internal, gauss = states["python"]
    random.setstate((version, tuple(internal), gauss))
