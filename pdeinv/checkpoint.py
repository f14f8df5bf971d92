"""Checkpoints of a training run: atomic files (:mod:`pdeinv.files`), and a refusal to resume a
different run.

Guarantees:

* **Atomic.** :meth:`Checkpoint.save` writes a temporary file in the checkpoint's
  own folder, flushes and ``fsync``\\ s it, ``os.replace``\\ s it over the target
  and ``fsync``\\ s the folder. A process killed at any moment (SIGKILL included)
  leaves the previous checkpoint or the new one, never a mix or a partial file;
  after the folder's ``fsync`` the new one also survives a power loss. A save
  that fails (a full disk) raises ``OSError`` saying so and leaves the previous
  checkpoint intact. A
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

What a checkpoint holds is decided by :class:`pdeinv.Trainer` (model, rule state,
RNG states, step, history); this module only stores and compares it.
"""

from __future__ import annotations

import json
import os
import random
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ._checks import count
from .files import atomic_write, remove_stale_temporaries

#: re-exported for one release: import them from :mod:`pdeinv.files`
__all__ = ["Checkpoint", "atomic_write", "check_identity", "network_identity", "plain", "rng_states",
           "set_rng_states"]

FORMAT = "pdeinv-checkpoint"
VERSION = 2  # 2: rule state = transformation + steps; identity with hyper-parameters


@dataclass
class Checkpoint:
    """Where a run is checkpointed and how often: every ``every`` steps and after the last.

    ``Trainer(..., checkpoint=Checkpoint("run/checkpoint.pt", every=50), resume=True)``
    continues from ``run/checkpoint.pt`` if it exists.
    """

    path: str | os.PathLike
    every: int = 100

    def __post_init__(self):
        """Creates the folder and proves it writable now, so a bad path fails before training
        (``ValueError`` naming it), not at the first save."""
        import tempfile

        self.path = Path(self.path)
        self.every = count(self.every, "checkpoint every")
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


def _describe_network(net: dict) -> str:
    shapes = net["shapes"]
    return f"{net['class']} ({', '.join(f'{k} {tuple(s)}' for k, s in shapes.items())})"


def _differences(saved: dict, current: dict) -> str:
    """``key=saved (checkpoint) vs current (this run)`` for every key whose values differ."""
    keys = [k for k in dict.fromkeys([*saved, *current]) if saved.get(k) != current.get(k)]
    return ", ".join(f"{k}={saved.get(k)!r} (checkpoint) vs {current.get(k)!r} (this run)" for k in keys)


def check_identity(saved: dict, current: dict, path) -> None:
    """Refuse (``ValueError``) when the checkpoint at ``path`` belongs to a different run."""
    where = f"checkpoint {str(path)!r}"
    if saved["problem"] != current["problem"]:
        raise ValueError(f"{where} is of problem {saved['problem']!r}, this run is {current['problem']!r}; "
                         "use another output folder or the same problem")
    diff = _differences(saved["settings"], current["settings"])
    if diff:
        raise ValueError(f"{where} is of problem {saved['problem']!r} with other settings: {diff}")
    s_net, c_net = saved["network"], current["network"]
    if s_net != c_net:
        diff = _differences(s_net.get("architecture", {}), c_net.get("architecture", {}))
        raise ValueError(f"{where} holds network {_describe_network(s_net)}; this run's network is "
                         f"{_describe_network(c_net)}" + (f": {diff}" if diff else ""))
    if saved["rule"] != current["rule"]:
        raise ValueError(f"{where} was written with rule {saved['rule']!r}; this run has {current['rule']!r}")
    diff = _differences(saved["hyperparameters"], current["hyperparameters"])
    if diff:
        raise ValueError(f"{where} was written with rule {saved['rule']!r} and other hyper-parameters: "
                         f"{diff}; resume with the same settings (only --steps / --time-budget may change)")
    if saved["trainer"] != current["trainer"]:
        raise ValueError(f"{where} was written with trainer {saved['trainer']!r}; "
                         f"this run has {current['trainer']!r}")


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
