"""Checkpoints of a training run: atomic files, and a refusal to resume a different run.

Guarantees:

* **Atomic.** :meth:`Checkpoint.save` writes a temporary file in the checkpoint's
  own folder, flushes and ``fsync``\\ s it, ``os.replace``\\ s it over the target
  and ``fsync``\\ s the folder. A process killed at any moment (SIGKILL included)
  leaves the previous checkpoint or the new one, never a mix or a partial file;
  after the folder's ``fsync`` the new one also survives a power loss. A
  temporary left behind by a killed save is removed by the next save.
* **Safe to load.** Files are read with ``torch.load(weights_only=True)``: a
  checkpoint can hold tensors, numbers, strings, lists and dicts, never code.
  Anything unreadable is reported as a corrupt checkpoint (``ValueError``).
* **Same run only.** A checkpoint records an *identity* — problem name and
  settings, network class and parameter shapes, update rule, and the trainer's
  data settings (seed, n_train, n_test, batch_size, dtype). :func:`check_identity`
  refuses to resume when any of them differs, naming both values.

What a checkpoint holds is decided by :class:`pdeinv.Trainer` (model, rule state,
RNG states, step, history); this module only stores and compares it.
"""

from __future__ import annotations

import json
import os
import random
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ._checks import count

FORMAT = "pdeinv-checkpoint"
VERSION = 1


@dataclass
class Checkpoint:
    """Where a run is checkpointed and how often: every ``every`` steps and after the last.

    ``Trainer(..., checkpoint=Checkpoint("run/checkpoint.pt", every=50), resume=True)``
    continues from ``run/checkpoint.pt`` if it exists.
    """

    path: str | os.PathLike
    every: int = 100

    def __post_init__(self):
        self.path = Path(self.path)
        self.every = count(self.every, "checkpoint every")

    def exists(self) -> bool:
        return self.path.is_file()

    def save(self, payload: dict) -> None:
        """Write ``payload`` atomically (see the module docstring)."""
        payload = {"format": FORMAT, "version": VERSION, **payload}
        _remove_stale_temporaries(self.path)
        atomic_write(self.path, lambda fh: torch.save(payload, fh))

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


def atomic_write(path, write) -> None:
    """``write(fh)`` into a temporary file beside ``path``, fsync, ``os.replace``, fsync the folder."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # platforms without directory handles (Windows): os.replace is still atomic
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _remove_stale_temporaries(path: Path) -> None:
    """Temporaries of this checkpoint left by a killed save (one writer per checkpoint assumed)."""
    for stale in path.parent.glob(f".{path.name}.*.tmp"):
        stale.unlink(missing_ok=True)


# -- identity: what must match to resume ---------------------------------------------------------

def plain(value):
    """``value`` as JSON-able builtins (numpy arrays -> lists, paths -> str), for saving and comparing."""
    def default(v):
        if isinstance(v, np.ndarray):
            return v.tolist()
        if isinstance(v, np.generic):
            return v.item()
        if isinstance(v, torch.dtype):
            return str(v)
        return str(v)

    return json.loads(json.dumps(value, default=default))


def network_identity(model: torch.nn.Module) -> dict:
    return {"class": type(model).__qualname__,
            "shapes": {k: list(v.shape) for k, v in model.state_dict().items()}}


def _describe_network(net: dict) -> str:
    shapes = net["shapes"]
    return f"{net['class']} ({', '.join(f'{k} {tuple(s)}' for k, s in shapes.items())})"


def check_identity(saved: dict, current: dict, path) -> None:
    """Refuse (``ValueError``) when the checkpoint at ``path`` belongs to a different run."""
    where = f"checkpoint {str(path)!r}"
    if saved["problem"] != current["problem"]:
        raise ValueError(f"{where} is of problem {saved['problem']!r}, this run is {current['problem']!r}; "
                         "use another output folder or the same problem")
    s_set, c_set = saved["settings"], current["settings"]
    diff = sorted(k for k in set(s_set) | set(c_set) if s_set.get(k) != c_set.get(k))
    if diff:
        both = ", ".join(f"{k}={s_set.get(k)!r} (checkpoint) vs {c_set.get(k)!r} (this run)" for k in diff)
        raise ValueError(f"{where} is of problem {saved['problem']!r} with other settings: {both}")
    if saved["network"] != current["network"]:
        raise ValueError(f"{where} holds network {_describe_network(saved['network'])}; this run's "
                         f"network is {_describe_network(current['network'])}")
    for key in ("rule", "trainer"):
        if saved[key] != current[key]:
            raise ValueError(f"{where} was written with {key} {saved[key]!r}; this run has {current[key]!r}")


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
