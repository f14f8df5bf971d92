"""Data-parallel training on ``torch.distributed``: one strategy object the trainer is given.

**Contract:** ``torchrun --nproc_per_node=P -m pdeinv train …`` trains with ``P`` processes
(gloo on CPU, NCCL on CUDA). :func:`from_env` reads torchrun's ``WORLD_SIZE`` / ``RANK`` /
``LOCAL_RANK`` and returns :class:`Single` (the default, one process) or :class:`DataParallel`.

**The maths.** Every rank holds the same parameters θ and draws the same global batch of
``B`` observations (same seed); rank ``r`` of ``P`` keeps rows ``[r·b, (r+1)·b)``, ``b = B/P``,
and runs the physics of its shard only. GD's and SIP's losses are batch means,

    L(θ) = (1/B) Σ_i ℓ_i(θ) = (1/P) Σ_r L_r(θ),   L_r = (1/b) Σ_{i ∈ shard r} ℓ_i,

which holds because the shards are equal (``B`` must divide by ``P``; refused otherwise), so
the mean over ranks of the shard gradients ``∇L_r`` (one ``all_reduce`` SUM, divided by
``P``) *is* the single-process gradient ``∇L``, up to the order of float additions. The
reported loss (and SIP's proxy) is averaged the same way. Every rank then applies the same
update with the same optimizer, so the parameters stay identical without a broadcast.

**Why not ``DistributedDataParallel``.** Our rules return a direction from
``torch.autograd.grad`` (:class:`~pdeinv.methods.base.Update`) instead of calling
``.backward()`` on a wrapped module, which is what DDP's gradient hooks need; averaging
the direction with one flattened ``all_reduce`` (in the parameters' dtype) is the same
communication DDP does.

**Only gradient-like rules.** A rule whose transformation is an optimizer step (the
direction is a gradient of the batch-mean loss: GD, Adam, SIP's proxy) is averaged as
above. HIG's step ``−η V Λ^{-1/2} Uᵀ g`` is a non-linear function of the Jacobian stacked
over the *whole* batch, so shard steps do not average to it. A rule with ``data_parallel``
(HIG) sums what it needs itself (:meth:`sum`): on the Kronecker route (the default networks)
the batch enters only through two sums over rows, ``Z̃ᵀZ̃`` and ``Z̃ᵀ R Q_C``
(:mod:`pdeinv.methods.hig.kron`), so every rank computes the single-process step from one
``all_reduce`` of ``k̃² + k̃·r`` numbers. HIG's Jacobian routes (other networks) are refused:
gathering the Jacobian rows (``batch·n_out × n_params`` floats) to decompose them on every
rank would cost more than the one physics call per step that sharding saves.

**Agreement, never a deadlock.** Decisions that could differ between ranks are reduced:
the guard sees the *reduced* loss and direction (a NaN on any rank is a NaN on all, so all
reject or accept the same step and roll back together); a rank whose rule raises a
non-finite error contributes NaN instead of leaving the collective; stopping (time budget,
callbacks) is :meth:`agree`\\ d. Ranks check at start that they run the same thing
(:meth:`check_same`). A rank that dies makes the others fail in the next collective
(gloo reports the closed connection; :data:`TIMEOUT_S` bounds any wait) and torchrun
stops the rest.

**Writer.** Only rank 0 (:attr:`is_writer`) writes: run folder, checkpoints, metrics,
plots, exports, warnings and the progress bar.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from datetime import timedelta

import torch

from ..errors import NonFiniteError
from ..methods.base import Rule, Update, trainable

__all__ = ["DataParallel", "Single", "TIMEOUT_S", "from_env", "rank_from_env", "world_size_from_env"]

#: seconds any collective may wait for the other ranks (env PDEINV_DDP_TIMEOUT overrides)
TIMEOUT_S = 120.0


class Single:
    """One process: every batch is its own shard, nothing to reduce or agree on."""

    world_size, rank, is_writer = 1, 0, True

    def check_batch(self, batch_size: int) -> None:
        pass

    def check_same(self, what: str, identity) -> None:
        pass

    def rule(self, rule):
        return rule

    def agree(self, flag: bool) -> bool:
        return bool(flag)

    def close(self) -> None:
        pass


@dataclass
class DataParallel:
    """``P`` processes of one ``torch.distributed`` group (module docstring).

    ``init_process_group`` is called by :func:`from_env` (or by you, before making this).
    """

    world_size: int
    rank: int

    @property
    def is_writer(self) -> bool:
        return self.rank == 0

    def check_batch(self, batch_size: int) -> None:
        """Refuse a global batch that does not split into ``world_size`` equal shards."""
        if batch_size % self.world_size:
            raise ValueError(f"batch_size={batch_size} does not split over {self.world_size} processes; "
                             f"expected a multiple of the number of processes (e.g. "
                             f"{max(1, batch_size // self.world_size) * self.world_size}), at least "
                             f"{self.world_size}")

    def shard(self, batch: torch.Tensor) -> torch.Tensor:
        """This rank's rows ``[r·b, (r+1)·b)`` of the global batch, ``b = B / P``."""
        b = len(batch) // self.world_size
        return batch[self.rank * b:(self.rank + 1) * b]

    def check_same(self, what: str, identity) -> None:
        """All-gather a hash of ``identity`` (a dict, or a function returning one) and refuse
        (``ValueError``, on every rank) if any rank differs, naming the first differing key with
        rank 0's and that rank's values."""
        import torch.distributed as dist

        identity = identity() if callable(identity) else identity
        mine = hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()
        hashes = [None] * self.world_size
        dist.all_gather_object(hashes, mine)
        if len(set(hashes)) == 1:
            return
        everyone = [None] * self.world_size
        dist.all_gather_object(everyone, identity)
        other = next(r for r, h in enumerate(hashes) if h != hashes[0])
        keys = sorted(set(everyone[0]) | set(everyone[other]), key=str)
        key = next(k for k in keys if everyone[0].get(k) != everyone[other].get(k))
        raise ValueError(f"the {self.world_size} processes do not run the same {what}: {key} is "
                         f"{everyone[0].get(key)!r} on rank 0 but {everyone[other].get(key)!r} on rank "
                         f"{other}; start every rank with the same command line")

    def rule(self, rule):
        """``rule`` (declared, :mod:`pdeinv.methods.protocol`) run on this rank's shard with directions
        averaged over the ranks: its own data-parallel form (``rule.data_parallel``)."""
        own = rule.data_parallel(self.sum, self.world_size)
        if own is None:
            raise ValueError(f"rule {rule.name!r} cannot run on {self.world_size} processes: it declares "
                             "no data-parallel form (its step is not a mean of per-sample directions); "
                             "run it with one process, or use gd, adam or sip")
        return Sharded(own, self)

    def sum(self, arrays: list) -> list:
        """Element-wise sums over the ranks of numpy arrays (one float64 ``all_reduce`` SUM)."""
        import numpy as np
        import torch.distributed as dist

        flat = torch.from_numpy(np.concatenate([np.ravel(a) for a in arrays]).astype(np.float64))
        flat = flat.to(self._device)
        dist.all_reduce(flat, op=dist.ReduceOp.SUM)
        flat, out, at = flat.cpu().numpy(), [], 0
        for a in arrays:
            out.append(flat[at:at + np.size(a)].reshape(np.shape(a)))
            at += np.size(a)
        return out

    def average(self, params: list, direction, info: dict):
        """Mean over ranks of ``direction`` and of ``info``'s numbers (two ``all_reduce`` SUMs / P):
        ``(direction, info)``, or ``(None, info)`` when the mean loss is not finite.

        The buffer covers every parameter in ``params`` (zeros where the rule leaves one alone);
        a rank without a direction (its loss was not finite) sends NaN, so the mean loss is NaN on
        every rank and all of them reject the step together.
        """
        import torch.distributed as dist

        keys = sorted(k for k, v in info.items() if isinstance(v, (int, float)) and not isinstance(v, bool))
        device = params[0].device
        # the parameters' own precision on the wire (float32 for the default MLP), the numbers in float64
        dtype = params[0].dtype if all(p.dtype == params[0].dtype for p in params) else torch.float64
        if direction is None:
            flat = torch.full((sum(p.numel() for p in params),), math.nan, dtype=dtype, device=device)
        else:
            flat = torch.cat([(torch.zeros_like(p) if d is None else d.detach()).reshape(-1).to(dtype)
                              for p, d in zip(params, direction, strict=True)])
        numbers = torch.tensor([float(info[k]) for k in keys], dtype=torch.float64, device=device)
        dist.all_reduce(flat, op=dist.ReduceOp.SUM)
        dist.all_reduce(numbers, op=dist.ReduceOp.SUM)
        flat /= self.world_size
        numbers /= self.world_size
        info = {**info, **dict(zip(keys, numbers.tolist(), strict=True))}
        if direction is None or not math.isfinite(info.get("loss", math.nan)):
            return None, info
        out, at = [], 0
        for p, d in zip(params, direction, strict=True):
            out.append(None if d is None else flat[at:at + p.numel()].reshape(p.shape).to(d.dtype))
            at += p.numel()
        return tuple(out), info

    def agree(self, flag: bool) -> bool:
        """True on every rank if it is True on any (``all_reduce`` MAX)."""
        import torch.distributed as dist

        t = torch.tensor([1 if flag else 0], device=self._device)
        dist.all_reduce(t, op=dist.ReduceOp.MAX)
        return bool(t.item())

    @property
    def _device(self):
        import torch.distributed as dist

        return torch.device("cuda", torch.cuda.current_device()) if dist.get_backend() == "nccl" \
            else torch.device("cpu")

    def close(self) -> None:
        import torch.distributed as dist

        if dist.is_initialized():
            dist.destroy_process_group()


class Sharded(Rule):
    """A rule seen through :class:`DataParallel`: ``update`` on the shard, averaged over ranks;
    everything else (name, transform, declarations, state, hyper-parameters) is the rule's own."""

    def __init__(self, rule: Rule, parallel: DataParallel):
        self.inner, self.parallel = rule, parallel
        self.name, self.transform = rule.name, rule.transform
        self.accepts_target, self.resumable = rule.accepts_target, rule.resumable

    def init(self, problem, model):
        return self.inner.init(problem, model)

    def calibrate(self, state, model, y):
        return self.inner.calibrate(state, model, y)

    def default_target(self):
        return self.inner.default_target()

    def state_dict(self, state) -> dict:
        return self.inner.state_dict(state)

    def load_state_dict(self, state, sd: dict):
        return self.inner.load_state_dict(state, sd)

    def hyperparameters(self) -> dict:
        return self.inner.hyperparameters()

    def update(self, state, model, y, target=None):
        try:
            shard = self.parallel.shard
            direction, info = self.inner.update(state, model, shard(y)) if target is None else \
                self.inner.update(state, model, shard(y), target=shard(target))
        except NonFiniteError:  # e.g. a non-finite network output: join the collective with NaN
            direction, info = None, {"loss": math.nan}
        return Update(*self.parallel.average(trainable(model), direction, info))


def world_size_from_env() -> int:
    """``WORLD_SIZE`` as torchrun sets it (1 without torchrun)."""
    raw = os.environ.get("WORLD_SIZE", "1")
    try:
        world = int(raw)
    except ValueError:
        raise ValueError(f"WORLD_SIZE={raw!r} is not an integer; launch with torchrun") from None
    if world < 1:  # torchrun sets at least 1
        raise ValueError(f"WORLD_SIZE={raw!r} is not a number of processes; expected an integer >= 1 "
                         "(torchrun sets it), or unset it for one process")
    return world


def rank_from_env() -> int:
    """``RANK`` as torchrun sets it (0 without torchrun)."""
    try:
        return int(os.environ.get("RANK", "0"))
    except ValueError:
        return 0


def timeout_s() -> float:
    raw = os.environ.get("PDEINV_DDP_TIMEOUT", str(TIMEOUT_S))
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not value > 0:
        raise ValueError(f"PDEINV_DDP_TIMEOUT={raw!r} is not allowed; expected seconds > 0")
    return value


def from_env(device: torch.device):
    """:class:`Single`, or :class:`DataParallel` after ``init_process_group`` when torchrun started
    more than one process (gloo on CPU, NCCL on CUDA, each rank on ``cuda:LOCAL_RANK``)."""
    world = world_size_from_env()
    if world <= 1:
        return Single()
    import torch.distributed as dist

    backend = "nccl" if device.type == "cuda" else "gloo"
    if backend == "nccl" and device.index is not None:
        raise ValueError(f"device {str(device)!r} puts all {world} processes on one GPU; with torchrun "
                         "give device 'cuda': each process takes cuda:LOCAL_RANK")
    if backend == "nccl":
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
    if not dist.is_initialized():
        try:
            dist.init_process_group(backend, timeout=timedelta(seconds=timeout_s()))
        except RuntimeError as err:  # torch.distributed.DistError: a store that timed out, a port in use
            from ..problem.definition import first_line

            raise ValueError(f"the {world} processes of WORLD_SIZE={world} did not form a group within "
                             f"PDEINV_DDP_TIMEOUT={timeout_s():g} s ({type(err).__name__}: "
                             f"{first_line(err)}): launch every rank, e.g. with `torchrun --nproc-per-node "
                             f"{world} -m pdeinv.cli train …`") from err
    return DataParallel(dist.get_world_size(), dist.get_rank())
