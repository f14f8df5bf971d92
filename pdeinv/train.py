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
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ._checks import count, nonnegative
from .methods.base import NonFiniteError, UpdateRule
from .nets import fit_input_scaling

#: ``callback(record, model) -> bool | None``; returning True stops training after this step
Callback = Callable[[dict, torch.nn.Module], "bool | None"]


@dataclass
class Result:
    """A finished run: the trained model, the per-step history and the final metrics."""

    model: torch.nn.Module
    history: list[dict]
    metrics: dict

    def write_history(self, path) -> None:
        write_csv(self.history, path)


def write_csv(history: list[dict], path) -> None:
    keys = list(dict.fromkeys(k for row in history for k in row))
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys)
        writer.writeheader()
        writer.writerows(history)


def _seed(seed: int, stream: int) -> int:
    """Independent integer seeds for training data, test data and batch order."""
    return int(np.random.SeedSequence([seed, stream]).generate_state(1)[0])


@dataclass
class Trainer:
    """Train ``model`` on ``problem`` with ``rule`` (a :class:`~pdeinv.methods.GD`, ``SIP``, ``HIG``, …).

    Data: ``n_train`` and ``n_test`` pairs from ``problem.sample`` with seeds derived
    from ``seed`` (the two sets are independent draws); batches are drawn without
    replacement, reshuffled every epoch. ``model=None`` takes ``problem.model()``
    after ``torch.manual_seed(seed)``; ``fit_scaling`` sets a model's input
    standardization from the training observations (if it has one).

    Stops after ``steps`` steps or once the training wall time exceeds
    ``time_budget`` seconds (at least one must be given), or when a callback
    returns True. A non-finite loss or update raises :class:`NonFiniteError`
    naming the step; the parameters stay those of the last good step and
    ``trainer.history`` keeps everything recorded so far.
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
    callbacks: list[Callback] = field(default_factory=list)
    progress: bool | None = None
    dtype: torch.dtype | None = None  # None: the model's own parameter dtype (float32 for the default MLP)
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

    # -- data and evaluation -------------------------------------------------------------
    def _data(self):
        x, y = self.problem.sample(self.n_train, _seed(self.seed, 1))
        xt, yt = self.problem.sample(self.n_test, _seed(self.seed, 2))
        dtype = self.dtype or torch.float32
        t = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
        return t(y), (xt, yt, t(yt))

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

    # -- the loop ------------------------------------------------------------------------
    def fit(self) -> Result:
        if self.model is None:
            torch.manual_seed(self.seed)
            self.model = self.problem.model()
        if self.dtype is None:
            self.dtype = getattr(next(iter(self.model.parameters()), None), "dtype", torch.float32)
        model = self.model.to(self.dtype)
        y_train, test = self._data()
        if self.fit_scaling:
            fit_input_scaling(model, y_train)
        state = self.rule.init(self.problem, model)
        gen = torch.Generator().manual_seed(_seed(self.seed, 3))
        order, pos = torch.randperm(self.n_train, generator=gen), 0
        self.history = []
        bar = _progress(self.steps, self.progress)
        wall, step, stop = 0.0, 0, False
        while not stop:
            if pos + self.batch_size > self.n_train:
                order, pos = torch.randperm(self.n_train, generator=gen), 0
            batch = y_train[order[pos:pos + self.batch_size]]
            pos += self.batch_size
            t0 = time.perf_counter()
            try:
                state, info = self.rule.step(state, model, batch)
            except NonFiniteError as err:
                bar.close()
                raise NonFiniteError(f"step {step + 1} ({getattr(self.rule, 'name', 'rule')}): "
                                     f"{err}") from None
            wall += time.perf_counter() - t0
            step += 1
            if not math.isfinite(info["loss"]):  # a rule that forgot to check
                raise NonFiniteError(f"step {step}: the y-loss is {info['loss']}")
            record = {"step": step, "wall_s": wall, **info}
            stop = (self.steps is not None and step >= self.steps) or (
                self.time_budget is not None and wall >= self.time_budget)
            if step % self.eval_every == 0 or stop or step == 1:
                record.update(self.evaluate(model, test))
            self.history.append(record)
            bar.update(1)
            bar.set_postfix(loss=f"{info['loss']:.3g}", refresh=False)
            for cb in self.callbacks:
                stop = bool(cb(record, model)) or stop
        bar.close()
        if "x_err" not in self.history[-1]:  # a callback stopped between evaluations
            self.history[-1].update(self.evaluate(model, test))
        last = self.history[-1]
        metrics = {
            "problem": getattr(self.problem, "name", None), "method": getattr(self.rule, "name", None),
            "steps": step, "wall_s": wall, "x_err": last["x_err"], "y_err": last["y_err"],
            "loss": last["loss"], "step_s": wall / step, "n_train": self.n_train,
            "n_test": self.n_test, "batch_size": self.batch_size, "seed": self.seed,
            "n_params": sum(p.numel() for p in model.parameters() if p.requires_grad),
        }
        return Result(model, self.history, metrics)


def _progress(total, enabled):
    """tqdm on an interactive terminal; silent when not a TTY, under CI, or if disabled."""
    from tqdm.auto import tqdm

    if enabled is None:
        enabled = sys.stderr.isatty() and not os.environ.get("CI")
    return tqdm(total=total, disable=not enabled, unit="step", leave=False)


def train(problem, rule, model=None, **kw) -> Result:
    """``Trainer(problem, rule, model, **kw).fit()``."""
    return Trainer(problem, rule, model, **kw).fit()
