"""The common trainer: one loop for every update rule (no ``if method == ...``).

Per step it records the batch y-loss (``½ · mean_i ‖P(f(y*_i)) − y*_i‖²``,
Euclidean) and the training wall time; every ``eval_every`` steps (and after the
last) the mean relative L²(Ω) errors on a held-out test set,

    x_err = mean_i ‖f(y*_i) − x_i‖_M / ‖x_i‖_M,   y_err = mean_i ‖P f(y*_i) − y*_i‖_M / ‖y*_i‖_M

(``y_err`` falls back to the Euclidean norm when observations are not fields on
the mesh, e.g. sensor time series). ``wall_s`` counts the training steps only,
not evaluations, so runs can be compared at equal wall-clock time.
"""

from __future__ import annotations

import csv
import io
import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ._checks import count, nonnegative, positive
from .checkpoint import (
    Checkpoint,
    atomic_write,
    check_identity,
    network_identity,
    plain,
    rng_states,
    set_rng_states,
)
from .methods.base import NonFiniteError, Resumable, UpdateRule
from .nets import fit_preconditioning

#: ``callback(record, model) -> bool | None``; returning True stops training after this step
Callback = Callable[[dict, torch.nn.Module], "bool | None"]


@dataclass
class Result:
    """A finished run: the trained model, the per-step history, the final metrics and rule state."""

    model: torch.nn.Module
    history: list[dict]
    metrics: dict
    state: object = None

    def write_history(self, path) -> None:
        write_csv(self.history, path)


def write_csv(history: list[dict], path) -> None:
    """Write ``history`` as CSV, atomically (a reader or a kill never sees half a file)."""
    keys = list(dict.fromkeys(k for row in history for k in row))
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=keys)
    writer.writeheader()
    writer.writerows(history)
    atomic_write(path, lambda fh: fh.write(text.getvalue().encode()))


#: the trainer's seed streams: training data, test data, batch order, held-out observations
TRAIN_DATA, TEST_DATA, BATCH_ORDER, VAL_DATA = 1, 2, 3, 4


def seed_stream(seed: int, stream: int) -> int:
    """Independent integer seed ``stream`` of ``seed`` (``SeedSequence([seed, stream])``).

    The trainer draws its training pairs from ``seed_stream(seed, TRAIN_DATA)``, its
    test pairs from ``seed_stream(seed, TEST_DATA)`` and its batch order from
    ``seed_stream(seed, BATCH_ORDER)``, so other code can rebuild exactly the same data.
    """
    return int(np.random.SeedSequence([seed, stream]).generate_state(1)[0])


@dataclass
class _Position:
    """Everything besides the model and the rule state that a resumed run must restore."""

    gen: torch.Generator  # batch order
    order: torch.Tensor
    pos: int = 0
    step: int = 0  # accepted steps
    wall: float = 0.0
    failures: int = 0  # consecutive rejected steps
    stopped_by: str | None = None  # a stopping rule or callback that ended the run


@dataclass
class Trainer:
    """Train ``model`` on ``problem`` with ``rule`` (a :class:`~pdeinv.methods.GD`, ``SIP``, ``HIG``, …).

    Data: ``n_train`` and ``n_test`` pairs from ``problem.sample`` with seeds derived
    from ``seed`` (the two sets are independent draws); batches are drawn without
    replacement, reshuffled every epoch. ``model=None`` takes ``problem.model()``
    after ``torch.manual_seed(seed)``; ``fit_scaling`` fits a model's input transform
    (PCA whitening, or the MLP's standardization) on the training observations with
    the problem's noise level (:func:`pdeinv.nets.fit_preconditioning`; never on ``x``).

    Stops after ``steps`` steps or once the training wall time exceeds
    ``time_budget`` seconds (at least one must be given), when a callback
    returns True, or when the stopping rule ``stop`` fires (e.g.
    :class:`~pdeinv.stopping.DiscrepancyStop`: checked every ``stop.every``
    accepted steps on ``stop.n_val`` held-out observations, drawn from their own
    seed stream; their ``x`` is never used). ``metrics["stopped_by"]`` says which
    (``steps``, ``time_budget``, the rule's name, or ``callback``) and
    ``metrics["steps"]`` at which step.

    **Non-finite guard.** A step whose loss, prediction or update holds NaN/Inf is
    *rejected*: the rule raises :class:`NonFiniteError` before touching the
    parameters (the contract of :mod:`pdeinv.methods.base`), so they stay those of
    the last good step. The trainer records the rejection in ``history`` (a row
    with the step number, ``loss`` NaN and the message under ``rejected``), warns,
    multiplies the rule's step size by ``step_factor`` (default ½: the optimizer's
    lr for GD/SIP, η for HIG, via ``rule.scale_step``) and retries with the next
    batch. After ``max_failures`` (default 5) consecutive rejections it raises
    :class:`NonFiniteError` naming the step and the last good checkpoint. The
    reduced step size is kept for the rest of the run (and checkpointed).

    **Checkpoints.** With ``checkpoint=Checkpoint(path, every=k)`` the run is saved
    atomically every ``k`` accepted steps and after the last one (see
    :mod:`pdeinv.checkpoint`): model and rule state, the step, history, wall time,
    and the torch / numpy / Python generator states with the batch order and its
    position. ``resume=True`` continues from that checkpoint (``FileNotFoundError``
    if there is none; ``ValueError`` if it belongs to another problem, network, rule
    or data setting). ``steps`` and ``time_budget`` may differ on resume, to extend
    a run. A resumed run repeats the uninterrupted one bitwise (losses, errors,
    parameters) on the same machine with the same torch/BLAS thread counts; with
    other thread counts reductions may be ordered differently and agreement is to
    float tolerance. Wall time spent after the last save is not counted.
    """

    problem: object
    rule: UpdateRule
    model: torch.nn.Module | None = None
    steps: int | None = 1000
    time_budget: float | None = None
    n_train: int = 1024
    n_test: int = 128
    batch_size: int = 32
    seed: int = 0
    eval_every: int = 50
    fit_scaling: bool = True
    stop: object | None = None  # a stopping rule (pdeinv.stopping), strategy object
    callbacks: list[Callback] = field(default_factory=list)
    progress: bool | None = None
    dtype: torch.dtype | None = None  # None: the model's own parameter dtype (float32 for the default MLP)
    checkpoint: Checkpoint | None = None
    resume: bool = False
    max_failures: int = 5
    step_factor: float = 0.5
    history: list[dict] = field(default_factory=list, init=False)

    def __post_init__(self):
        if self.steps is None and self.time_budget is None:
            raise ValueError("give steps=, time_budget= or both; otherwise training never stops")
        if self.steps is not None:
            self.steps = count(self.steps, "steps")
        if self.time_budget is not None:
            nonnegative(self.time_budget, "time_budget")
        self.n_train = count(self.n_train, "n_train")
        self.n_test = count(self.n_test, "n_test")
        self.batch_size = count(self.batch_size, "batch_size")
        if self.batch_size > self.n_train:
            raise ValueError(f"batch_size={self.batch_size} is larger than n_train={self.n_train}")
        self.eval_every = count(self.eval_every, "eval_every")
        self.max_failures = count(self.max_failures, "max_failures")
        positive(self.step_factor, "step_factor")
        if not self.step_factor <= 1:
            raise ValueError(f"step_factor={self.step_factor!r} is not allowed; "
                             "expected 0 < step_factor <= 1")
        if self.resume and self.checkpoint is None:
            raise ValueError("resume=True needs checkpoint=Checkpoint(path) to resume from")

    # -- data and evaluation -------------------------------------------------------------
    def _data(self):
        x, y = self.problem.sample(self.n_train, seed_stream(self.seed, TRAIN_DATA))
        xt, yt = self.problem.sample(self.n_test, seed_stream(self.seed, TEST_DATA))
        dtype = self.dtype or torch.float32
        t = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
        return y, t(y), (xt, yt, t(yt))

    def _start_stop(self, y_train: np.ndarray):
        """The stopping rule's state, with its held-out observations (x discarded)."""
        if self.stop is None:
            return None
        _, y_val = self.problem.sample(self.stop.n_val, seed_stream(self.seed, VAL_DATA))
        return self.stop.init(self.problem, y_train, y_val)

    @torch.no_grad()
    def evaluate(self, model, test) -> dict:
        """Mean relative L²(Ω) x- and y-errors on the test set."""
        x, y, y_t = test
        xhat = model(y_t).double().cpu().numpy()
        if not np.isfinite(xhat).all():
            return {"x_err": math.nan, "y_err": math.nan}
        yhat = self.problem.operator.forward(xhat)
        disc = self.problem.disc
        if yhat.shape[1] == disc.N:
            y_err = disc.relative_error(yhat, y)
        else:
            y_err = np.linalg.norm(yhat - y, axis=1) / np.linalg.norm(y, axis=1)
        return {"x_err": float(np.mean(self.problem.relative_error(xhat, x))),
                "y_err": float(np.mean(y_err))}

    # -- checkpoints ---------------------------------------------------------------------
    def identity(self, model) -> dict:
        """What a checkpoint must share with this run to be resumed by it."""
        return {"problem": getattr(self.problem, "name", None),
                "settings": plain(getattr(self.problem, "settings", {})),
                "network": network_identity(model), "rule": getattr(self.rule, "name", None),
                "trainer": {"seed": self.seed, "n_train": self.n_train, "n_test": self.n_test,
                            "batch_size": self.batch_size, "dtype": str(self.dtype)}}

    def _save(self, model, state, at: _Position) -> None:
        self.checkpoint.save({
            "identity": self.identity(model), "model": model.state_dict(),
            "rule_state": self.rule.state_dict(state),
            "position": {"gen": at.gen.get_state(), "order": at.order, "pos": at.pos, "step": at.step,
                         "wall": at.wall, "failures": at.failures, "stopped_by": at.stopped_by},
            "rng": rng_states(), "history": plain(self.history)})

    def _restore(self, model, state, at: _Position):
        ckpt = self.checkpoint
        if not ckpt.exists():
            raise FileNotFoundError(f"resume: there is no checkpoint at {str(ckpt.path)!r} to resume from "
                                    "(start without resume / --resume)")
        saved = ckpt.load()
        missing = sorted({"identity", "model", "rule_state", "position", "rng", "history"} - set(saved))
        if missing:
            raise ValueError(f"checkpoint {str(ckpt.path)!r} lacks {', '.join(missing)}: not written by "
                             "pdeinv.Trainer; delete it to start over")
        check_identity(saved["identity"], self.identity(model), ckpt.path)
        model.load_state_dict(saved["model"])  # copies into the same Parameters the optimizer holds
        state = self.rule.load_state_dict(state, saved["rule_state"])
        p = saved["position"]
        at.gen.set_state(p["gen"])
        at.order, at.pos, at.step, at.wall, at.failures = (p["order"], p["pos"], p["step"], p["wall"],
                                                           p["failures"])
        at.stopped_by = p.get("stopped_by")
        set_rng_states(saved["rng"])
        self.history = saved["history"]
        return state

    def _last_good(self) -> str:
        if self.checkpoint is None:
            return "checkpointing is off, nothing was saved"
        if not self.checkpoint.exists():
            return f"no checkpoint was written yet ({str(self.checkpoint.path)!r})"
        return f"last good checkpoint: {str(self.checkpoint.path)!r}"

    def _done(self, at: _Position) -> bool:
        return at.step >= 1 and (at.stopped_by is not None or (
            self.steps is not None and at.step >= self.steps) or (
            self.time_budget is not None and at.wall >= self.time_budget))

    # -- the loop ------------------------------------------------------------------------
    def fit(self) -> Result:
        if self.model is None:
            torch.manual_seed(self.seed)
            self.model = self.problem.model()
        if self.dtype is None:
            self.dtype = getattr(next(iter(self.model.parameters()), None), "dtype", torch.float32)
        model = self.model.to(self.dtype)
        resumable = isinstance(self.rule, Resumable)
        if self.checkpoint is not None and not resumable:
            raise ValueError(f"rule {getattr(self.rule, 'name', self.rule)!r} cannot be checkpointed: it "
                             "has no state_dict / load_state_dict / scale_step "
                             "(see pdeinv.methods.base.Resumable)")
        y_np, y_train, test = self._data()
        if self.fit_scaling:
            fit_preconditioning(model, y_np, getattr(self.problem, "noise", None) or None)
        stop_state = self._start_stop(y_np)
        state = self.rule.init(self.problem, model)
        gen = torch.Generator().manual_seed(seed_stream(self.seed, BATCH_ORDER))
        at = _Position(gen, torch.randperm(self.n_train, generator=gen))
        self.history = []
        if self.resume:
            state = self._restore(model, state, at)
        name = getattr(self.rule, "name", "rule")
        bar = _progress(self.steps, self.progress, at.step)
        stop = self._done(at)  # a resumed run that had already finished
        while not stop:
            if at.pos + self.batch_size > self.n_train:
                at.order, at.pos = torch.randperm(self.n_train, generator=at.gen), 0
            batch = y_train[at.order[at.pos:at.pos + self.batch_size]]
            at.pos += self.batch_size
            t0 = time.perf_counter()
            try:
                state, info = self.rule.step(state, model, batch)
            except NonFiniteError as err:
                at.wall += time.perf_counter() - t0
                at.failures += 1
                message = f"step {at.step + 1} ({name}): {err}"
                self.history.append({"step": at.step + 1, "wall_s": at.wall, "loss": math.nan,
                                     "rejected": message})
                if at.failures >= self.max_failures:
                    bar.close()
                    raise NonFiniteError(f"{message}; stopped after {at.failures} consecutive rejected "
                                         f"steps (max_failures={self.max_failures}); {self._last_good()}"
                                         ) from None
                if resumable:
                    state = self.rule.scale_step(state, self.step_factor)
                warnings.warn(f"{message}; step rejected, parameters unchanged, step size "
                              f"{'scaled by ' + format(self.step_factor, 'g') if resumable else 'kept'}"
                              f" (failure {at.failures} of at most {self.max_failures})",
                              RuntimeWarning, stacklevel=2)
                continue
            at.wall += time.perf_counter() - t0
            at.step += 1
            at.failures = 0
            if not math.isfinite(info["loss"]):  # a rule that forgot to check: it may have trained on it
                bar.close()
                raise NonFiniteError(f"step {at.step}: the y-loss is {info['loss']}")
            record = {"step": at.step, "wall_s": at.wall, **info}
            if stop_state is not None and at.step % self.stop.every == 0:
                t0 = time.perf_counter()  # part of training (a user pays for it), unlike the test evaluation
                stop_state, checked, fired = self.stop.check(stop_state, model)
                at.wall += time.perf_counter() - t0
                record.update(checked)
                if fired:
                    at.stopped_by = self.stop.name
            stop = self._done(at)
            if at.step % self.eval_every == 0 or stop or at.step == 1:
                record.update(self.evaluate(model, test))
            self.history.append(record)
            bar.update(1)
            bar.set_postfix(loss=f"{info['loss']:.3g}", refresh=False)
            for cb in self.callbacks:
                if cb(record, model) and not stop:
                    stop, at.stopped_by = True, "callback"
            if self.checkpoint is not None and (stop or at.step % self.checkpoint.every == 0):
                if stop and "x_err" not in record:  # a callback stopped between evaluations
                    record.update(self.evaluate(model, test))
                self._save(model, state, at)
        bar.close()
        if "x_err" not in self.history[-1]:  # a callback stopped between evaluations
            self.history[-1].update(self.evaluate(model, test))
        last = self.history[-1]
        step, wall = at.step, at.wall
        metrics = {
            "problem": getattr(self.problem, "name", None), "method": getattr(self.rule, "name", None),
            "steps": step, "wall_s": wall, "x_err": last["x_err"], "y_err": last["y_err"],
            "loss": last["loss"], "step_s": wall / step, "n_train": self.n_train,
            "n_test": self.n_test, "batch_size": self.batch_size, "seed": self.seed,
            "n_params": sum(p.numel() for p in model.parameters() if p.requires_grad),
            "rejected_steps": sum(1 for h in self.history if "rejected" in h),
            "stopped_by": at.stopped_by or ("steps" if self.steps is not None and step >= self.steps
                                            else "time_budget"),
        }
        if stop_state is not None:
            metrics["stop_rule"] = {"name": self.stop.name, **self.stop.describe(stop_state)}
        return Result(model, self.history, metrics, state)


def _progress(total, enabled, initial=0):
    """tqdm on an interactive terminal; silent when not a TTY, under CI, or if disabled."""
    from tqdm.auto import tqdm

    if enabled is None:
        enabled = sys.stderr.isatty() and not os.environ.get("CI")
    return tqdm(total=total, initial=initial, disable=not enabled, unit="step", leave=False)


def train(problem, rule, model=None, **kw) -> Result:
    """``Trainer(problem, rule, model, **kw).fit()``."""
    return Trainer(problem, rule, model, **kw).fit()
