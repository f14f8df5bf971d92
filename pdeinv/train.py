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

import inspect
import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ._checks import count, nonnegative
from .checkpoint import Checkpoint, check_identity, network_identity, plain, rng_states, set_rng_states
from .data import as_observations, explained, fingerprint, model_mismatch, split
from .distributed import Single
from .files import write_csv
from .methods.base import NonFiniteError, Resumable, UpdateRule
from .methods.guard import ADVICE, Guard
from .nets import fit_preconditioning
from .physics.capabilities import observes_field
from .physics.device import placed, resolve

__all__ = ["Callback", "Result", "Trainer", "seed_stream", "train", "write_csv"]

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
    stopped_by: str | None = None  # a stopping rule or callback that ended the run
    y_err0: float | None = None  # the test y-error of the network training started from (_check_evaluation)

    def saved(self) -> dict:
        return {"gen": self.gen.get_state(), "order": self.order, "pos": self.pos, "step": self.step,
                "wall": self.wall, "stopped_by": self.stopped_by, "y_err0": self.y_err0}

    def restore(self, p: dict) -> None:
        self.gen.set_state(p["gen"])
        self.order, self.pos, self.step, self.wall = p["order"], p["pos"], p["step"], p["wall"]
        self.stopped_by, self.y_err0 = p.get("stopped_by"), p.get("y_err0")


@dataclass
class _Run:
    """One fit's live objects: the model, the rule state, the data, the stopping rule's state."""

    model: torch.nn.Module
    state: object
    y_train: torch.Tensor
    t_train: torch.Tensor | None  # what P f(y) must match (float64) if not y_train (pdeinv.targets)
    test: tuple
    stop_state: object
    at: _Position
    guard: Guard  # step size, failures, lowest loss, last good state (methods.guard)


@dataclass
class Trainer:
    """Train ``model`` on ``problem`` with ``rule`` (a :class:`~pdeinv.methods.GD`, ``SIP``, ``HIG``, …).

    Data: ``n_train`` and ``n_test`` pairs from ``problem.sample`` with seeds derived
    from ``seed`` (the two sets are independent draws); batches are drawn without
    replacement, reshuffled every epoch (``batch_size=None``: every training row, each step).
    **Own data:** ``data=y`` (numpy ``(B, m)``, a
    tensor, or a torch ``Dataset`` of observations) replaces the samples; the last
    ``n_test`` rows are held out as the test set and, with a stopping rule, the
    ``stop.n_val`` rows before them as its observations (:func:`pdeinv.data.split`);
    ``n_train`` becomes the number of rows left. ``data_x`` ``(B, N)``, optional, are
    the true fields, used only for ``x_err`` on the test rows (without them
    ``metrics["x_err"]`` is None). The noise level is the problem's (``--set noise=``).
    ``model=None`` takes ``problem.model()``
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

    **Guard** (:class:`~pdeinv.methods.guard.Guard`, its policy there). A step whose loss,
    prediction or update holds NaN/Inf, whose finite loss exceeds ``max_loss_growth`` (default
    1e3; None: off) times the lowest accepted batch loss so far, or whose test predictions blow
    up at an evaluation is *rejected*: the **last good state** (the parameters and rule/optimizer
    state whose loss last passed, i.e. from before the update that blew up) is put back and the
    step-size multiplier (the optimizer's lr for GD/SIP, the step for HIG) multiplied by
    ``step_factor`` (½); ``history`` gets a row with the step number, ``loss`` NaN and the message
    under ``rejected``, and the trainer warns. After ``recover_after`` (50) accepted steps in a row
    the multiplier doubles back toward 1. ``max_failures`` (5) rejections in a row (re-accepting
    the rolled-back state does not end a streak), or a rejection with the multiplier at its floor
    ``min_scale`` (1e-12, ~40 halvings), raise :class:`NonFiniteError` naming the step, the
    last good state (the model is left in it) and the last checkpoint this run wrote.

    **Checkpoints.** With ``checkpoint=Checkpoint(path, every=k)`` the run is saved
    atomically every ``k`` accepted steps and after the last one (see
    :mod:`pdeinv.checkpoint`): model and rule state, the last good state, the step,
    the step-size multiplier and lowest loss, history, wall time, and the torch /
    numpy / Python generator states with the batch order and its position.
    ``resume=True`` continues from that checkpoint (``FileNotFoundError``
    if there is none; ``ValueError`` if it belongs to another problem, network
    architecture, rule or rule hyper-parameter (as configured, not as lowered by
    the guard), or data setting). ``steps`` and ``time_budget`` may differ on
    resume, to extend a run (``ValueError`` if ``steps`` is below the checkpoint's step).
    A resumed run repeats the uninterrupted one bitwise (losses, errors,
    parameters) on the same machine with the same torch/BLAS thread counts; with
    other thread counts reductions may be ordered differently and agreement is to
    float tolerance. Wall time spent after the last save is not counted.

    ``device`` (default ``"cpu"``): the model and the training data are moved there, and a
    dense, modal or SVD physics backend is applied there by torch
    (:mod:`pdeinv.physics.device`; time stepping stays on the CPU). An unknown device, or
    CUDA where there is none, is a ``ValueError``.

    **Data parallel.** ``parallel`` (default :class:`~pdeinv.distributed.Single`) is the
    strategy that shards each global batch over processes and averages the rule's direction
    and loss (:class:`~pdeinv.distributed.DataParallel`, from torchrun's environment by
    :func:`pdeinv.distributed.from_env`): ``batch_size`` is the *global* batch and must divide
    by the number of processes; all ranks agree on every stop and rejection; only the writer
    (rank 0) saves checkpoints, warns and shows progress. ``metrics["world_size"]`` records it.
    """

    problem: object
    rule: UpdateRule
    model: torch.nn.Module | None = None
    steps: int | None = 1000
    time_budget: float | None = None
    n_train: int = 1024
    n_test: int = 128
    batch_size: int | None = 32  # None: every training row in each step (full batch)
    seed: int = 0
    eval_every: int = 50
    fit_scaling: bool = True
    stop: object | None = None  # a stopping rule (pdeinv.stopping), strategy object
    target: object = "auto"  # what P f(y) must match (pdeinv.targets): "auto", None or a strategy
    callbacks: list[Callback] = field(default_factory=list)
    progress: bool | None = None
    dtype: torch.dtype | None = None  # None: the model's own parameter dtype (float32 for the default MLP)
    checkpoint: Checkpoint | None = None
    resume: bool = False
    max_failures: int = 5
    step_factor: float = 0.5
    max_loss_growth: float | None = 1e3
    min_scale: float = 1e-12
    recover_after: int | None = 50
    device: str | torch.device = "cpu"
    data: object = None  # own observations (B, m): array, tensor or torch Dataset
    data_x: object = None  # their true fields (B, N), for errors only
    parallel: object = field(default_factory=Single)  # pdeinv.distributed: Single or DataParallel
    history: list[dict] = field(default_factory=list, init=False)
    _target_info: dict | None = field(default=None, init=False, repr=False)
    _own: dict | None = field(default=None, init=False, repr=False)
    _saved_step: int | None = field(default=None, init=False, repr=False)
    _rule: object = field(default=None, init=False, repr=False)

    def __post_init__(self):
        if self.steps is None and self.time_budget is None:
            raise ValueError("give steps=, time_budget= or both; otherwise training never stops")
        if self.steps is not None:
            self.steps = count(self.steps, "steps")
        if self.time_budget is not None:
            nonnegative(self.time_budget, "time_budget")
        self.n_test = count(self.n_test, "n_test")
        if self.data is not None:
            self._own_data()
        self.n_train = count(self.n_train, "n_train")
        self.batch_size = self.n_train if self.batch_size is None else count(self.batch_size, "batch_size")
        if self.batch_size > self.n_train:
            raise ValueError(f"batch_size={self.batch_size} is larger than n_train={self.n_train}")
        self.eval_every = count(self.eval_every, "eval_every")
        self._guard()  # checks its settings
        if self.resume and self.checkpoint is None:
            raise ValueError("resume=True needs checkpoint=Checkpoint(path) to resume from")
        self.device = resolve(self.device)
        self.parallel.check_batch(self.batch_size)
        self._rule = self.parallel.rule(self.rule)  # the rule on this process's shard

    # -- data and evaluation -------------------------------------------------------------
    def _own_data(self) -> None:
        """Check ``data`` / ``data_x`` against the problem and hold out the test (and stop) rows."""
        y = as_observations(self.data, self.problem.operator.n_out, "data")
        x = None if self.data_x is None else as_observations(self.data_x, self.problem.N, "data_x")
        if x is not None and len(x) != len(y):
            raise ValueError(f"data_x has {len(x)} rows but data has {len(y)}; expected one x per y")
        mismatch = None if x is None else model_mismatch(self.problem.operator, x, y)
        if mismatch is not None and not explained(mismatch, self.problem.noise) and self.parallel.is_writer:
            warnings.warn(f"the data's y differ from this problem's P x by {mismatch:.3g} (mean "
                          f"‖P x − y‖/‖y‖ over the file's rows), more than its noise level "
                          f"{self.problem.noise:g} explains: another simulator, grid or column order? "
                          "(--set noise=… declares noisy data)", RuntimeWarning, stacklevel=3)
        train, val, test = split(len(y), self.n_test, self.stop.n_val if self.stop is not None else 0)
        held = len(y) - train.stop
        if train.stop < held and self.parallel.is_writer:  # say what the default splits took
            stop = f" and {val.stop - val.start} for the stopping rule" if val.stop > val.start else ""
            warnings.warn(f"the data's {len(y)} rows: the last {test.stop - test.start} are held out as the "
                          f"test set{stop}, only {train.stop} train; hold out fewer with --n-test "
                          "(Trainer(n_test=...))", RuntimeWarning, stacklevel=3)
        self.n_train = train.stop
        self._own = {"y": y[train], "y_val": y[val], "y_test": y[test],
                     "x_test": None if x is None else x[test], "fingerprint": fingerprint(y),
                     "model_mismatch": mismatch,
                     "rows": {"train": [0, train.stop], "stop": [val.start, val.stop],
                              "test": [test.start, test.stop]}}

    def _data(self):
        """``(y_train numpy, y_train torch, (x_test, y_test numpy, y_test torch))`` on ``device``
        (``x_test`` None for own data without x)."""
        if self._own is not None:
            y = self._own["y"]
        else:
            _, y = self.problem.sample(self.n_train, seed_stream(self.seed, TRAIN_DATA))
        xt, yt = self.held_out()
        dtype = self.dtype or torch.float32
        t = lambda a: torch.as_tensor(a, dtype=dtype, device=self.device)  # noqa: E731
        return y, t(y), (xt, yt, t(yt))

    def held_out(self) -> tuple:
        """The test set ``(x or None, y)`` as numpy: own data's last rows, or the seeded samples."""
        if self._own is not None:
            return self._own["x_test"], self._own["y_test"]
        return self.problem.sample(self.n_test, seed_stream(self.seed, TEST_DATA))

    def _start_stop(self, y_train: np.ndarray):
        """The stopping rule's state, with its held-out observations (x discarded)."""
        if self.stop is None:
            return None
        if self._own is not None:
            y_val = self._own["y_val"]
        else:
            _, y_val = self.problem.sample(self.stop.n_val, seed_stream(self.seed, VAL_DATA))
        return self.stop.init(self.problem, y_train, y_val)

    @torch.no_grad()
    def evaluate(self, model, test) -> dict:
        """Mean relative L²(Ω) x- and y-errors on the test set (no ``x_err`` when ``x`` is None)."""
        x, y, y_t = test
        xhat = model(y_t).double().cpu().numpy()
        if not np.isfinite(xhat).all():
            return {"y_err": math.nan} if x is None else {"x_err": math.nan, "y_err": math.nan}
        yhat = self.problem.operator.forward(xhat)
        disc = self.problem.disc
        if observes_field(self.problem.operator):  # declared, never guessed from shapes
            y_err = disc.relative_error(yhat, y)
        else:
            y_err = np.linalg.norm(yhat - y, axis=1) / np.linalg.norm(y, axis=1)
        if x is None:
            return {"y_err": float(np.mean(y_err))}
        return {"x_err": float(np.mean(self.problem.relative_error(xhat, x))),
                "y_err": float(np.mean(y_err))}

    # -- checkpoints ---------------------------------------------------------------------
    def identity(self, model) -> dict:
        """What a checkpoint must share with this run to be resumed by it (the rule's *configured*
        hyper-parameters: the guard's lowered step size is run state, not identity)."""
        trainer = {"seed": self.seed, "n_train": self.n_train, "n_test": self.n_test,
                   "batch_size": self.batch_size, "dtype": str(self.dtype),
                   "target": getattr(self.target, "name", self.target)}
        if self._own is not None:
            trainer["data"] = self._own["fingerprint"]
        return {"problem": getattr(self.problem, "name", None),
                "settings": plain(getattr(self.problem, "settings", {})),
                "network": network_identity(model), "rule": getattr(self.rule, "name", None),
                "hyperparameters": plain(self.rule.hyperparameters()), "trainer": trainer}

    def _save(self, run: _Run) -> None:
        self.checkpoint.save({
            "identity": self.identity(run.model), "model": run.model.state_dict(),
            "rule_state": self.rule.state_dict(run.state), "position": run.at.saved(),
            "guard": run.guard.state_dict(), "rng": rng_states(), "history": plain(self.history)})
        self._saved_step = run.at.step

    def _restore(self, run: _Run) -> None:
        ckpt = self.checkpoint
        if not ckpt.exists():
            raise FileNotFoundError(f"resume: there is no checkpoint at {str(ckpt.path)!r} to resume from "
                                    "(start without resume / --resume)")
        saved = ckpt.load()
        missing = sorted({"identity", "model", "rule_state", "position", "rng", "history"} - set(saved))
        if missing:
            raise ValueError(f"checkpoint {str(ckpt.path)!r} lacks {', '.join(missing)}: not written by "
                             "pdeinv.Trainer; delete it to start over")
        check_identity(saved["identity"], self.identity(run.model), ckpt.path)
        done = saved["position"]["step"]
        if self.steps is not None and self.steps < done:
            raise ValueError(f"resume: checkpoint {str(ckpt.path)!r} has {done} steps done; "
                             f"steps={self.steps} is below that (give steps >= {done} to extend the run, "
                             "or start over)")
        run.model.load_state_dict(saved["model"])  # copies into the same Parameters the optimizer holds
        run.state = self.rule.load_state_dict(run.state, saved["rule_state"])
        run.at.restore(saved["position"])
        run.guard.load_state_dict(saved.get("guard") or {**saved["position"], "good": saved.get("good")})
        set_rng_states(saved["rng"])
        self.history = saved["history"]
        self._saved_step = done

    def _last_good(self, run: _Run) -> str:
        """The last good state the model was put back to, and the last checkpoint *this* run wrote."""
        state = "no step was verified" if run.guard.good.step is None else \
            f"the model holds the last good state (after step {run.guard.good.step})"
        if self.checkpoint is None:
            return f"{state}; checkpointing is off, nothing was saved"
        if self._saved_step is None:
            return f"{state}; no checkpoint was written yet ({str(self.checkpoint.path)!r})"
        return f"{state}; last good checkpoint: {str(self.checkpoint.path)!r} (step {self._saved_step})"

    def _done(self, at: _Position) -> bool:
        return at.step >= 1 and (at.stopped_by is not None or (
            self.steps is not None and at.step >= self.steps) or (
            self.time_budget is not None and at.wall >= self.time_budget))

    # -- the loop ------------------------------------------------------------------------
    def _guard(self) -> Guard:
        return Guard(self.max_failures, self.step_factor, self.max_loss_growth, self.min_scale,
                     self.recover_after)

    def _start(self) -> _Run:
        """Model on ``device``, data, preconditioning, rule and stopping states, batch order; resumed."""
        if self.model is None:
            torch.manual_seed(self.seed)
            self.model = self.problem.model()
        if self.dtype is None:
            self.dtype = getattr(next(iter(self.model.parameters()), None), "dtype", torch.float32)
        model = self.model.to(device=self.device, dtype=self.dtype)
        if self.checkpoint is not None and not isinstance(self.rule, Resumable):
            raise ValueError(f"rule {getattr(self.rule, 'name', self.rule)!r} cannot be checkpointed: it "
                             "has no state_dict / load_state_dict / hyperparameters "
                             "(see pdeinv.methods.base.Resumable)")
        y_np, y_train, test = self._data()
        t_train = self._fit_target(y_np, y_train, model)
        if self.fit_scaling:  # a fitted target is denoised: the input keeps every direction (drop=0),
            # each scaled at most to the noise floor σ² (clean data's rounding-level directions stay small)
            noise = getattr(self.problem, "noise", None) or None
            fit_preconditioning(model, y_np, noise, **({"drop": 0} if self._target_info else {}))
        stop_state = self._start_stop(y_np)
        self.parallel.check_same("run", lambda: {
            **self.identity(model), "steps": self.steps, "time_budget": self.time_budget,
            "eval_every": self.eval_every, "resume": self.resume, "stop": getattr(self.stop, "name", None)})
        gen = torch.Generator().manual_seed(seed_stream(self.seed, BATCH_ORDER))
        run = _Run(model, self._rule.init(placed(self.problem, self.device), model), y_train, t_train, test,
                   stop_state, _Position(gen, torch.randperm(self.n_train, generator=gen)), self._guard())
        calibrate = getattr(self._rule, "calibrate", None)  # e.g. SIP's proxy curvature, on the first batch
        if callable(calibrate):
            run.state = calibrate(run.state, model, y_train[run.at.order[:self.batch_size]])
        self.history = []
        if self.resume:
            self._restore(run)
        if run.at.y_err0 is None:  # a fresh run (a resumed one keeps its starting point's)
            start = self.evaluate(model, test)["y_err"]
            run.at.y_err0 = start if math.isfinite(start) else 1.0
        return run

    def _fit_target(self, y_np: np.ndarray, y_train: torch.Tensor, model=None) -> torch.Tensor | None:
        """What ``P f(y)`` must match when it is not ``y_train`` itself (``None``): ``target(y)`` when
        the target strategy fits one (:mod:`pdeinv.targets`), else the float64 ``y`` when the network's
        dtype is lower (a float32 copy of ``y`` puts rounding 6e-8 into every residual, which SIP's
        local inverse amplifies by up to ``1/(2√α)``). A rule whose ``update`` takes no ``target``
        keeps ``y`` (precision) or is refused (a fitted target). A strategy whose ``fit`` takes
        ``model=`` gets the network (a fixed decoder changes the basis the target filters in)."""
        from .methods.base import takes_target
        from .targets import SpectralWiener

        strategy = SpectralWiener() if self.target == "auto" else self.target
        noise = getattr(self.problem, "noise", None) or 0.0
        if strategy is None and noise > 0:
            warnings.warn(f"noise={noise:g} and target=None: every rule converges to the least-squares fit "
                          "of the noise and only a stopping rule regularizes (SIP's default inverse on a "
                          "spectral basis gets there in one step); keep target='auto'", RuntimeWarning,
                          stacklevel=4)
        fitted = None
        if strategy is not None:
            kw = {"model": model} if "model" in inspect.signature(strategy.fit).parameters else {}
            fitted = strategy.fit(self.problem, y_np, noise or None, **kw)
        if fitted is not None and not takes_target(self.rule):
            if self.target != "auto":
                raise ValueError(f"rule {getattr(self.rule, 'name', self.rule)!r} cannot use target="
                                 f"{self.target!r}: its update(state, model, y) takes no target=")
            fitted = None  # "auto" falls back to y for a rule that cannot take one
        if fitted is not None:
            self._target_info = fitted.info
        elif y_train.dtype == torch.float64 or not takes_target(self.rule):
            return None
        goal = np.asarray(y_np, dtype=float) if fitted is None else fitted(y_np)
        return torch.as_tensor(goal, dtype=torch.float64, device=y_train.device)

    def _batch(self, run: _Run) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The next batch (network dtype) and its float64 targets (``None``: the batch itself): without
        replacement, reshuffled every epoch."""
        at = run.at
        if at.pos + self.batch_size > self.n_train:
            at.order, at.pos = torch.randperm(self.n_train, generator=at.gen), 0
        rows = at.order[at.pos:at.pos + self.batch_size]
        at.pos += self.batch_size
        return run.y_train[rows], None if run.t_train is None else run.t_train[rows]

    def _step(self, run: _Run, batch: tuple, bar) -> dict | None:
        """One guarded step: its info, or ``None`` if rejected (last good state back, step size lowered)."""
        at, t0 = run.at, time.perf_counter()
        try:
            run.state, info = run.guard.step(self._rule, run.state, run.model, *batch)
        except NonFiniteError as err:
            at.wall += time.perf_counter() - t0
            self._reject(run, err, bar)
            return None
        at.wall += time.perf_counter() - t0
        at.step += 1
        return info

    def _reject(self, run: _Run, err: NonFiniteError, bar, failed: int | None = None) -> None:
        """Record a rejected step (``failed``: its number, default the next one) and let the guard roll
        back and lower the step size; raise when it says the run must stop."""
        failed = run.at.step + 1 if failed is None else failed
        message = f"step {failed} ({getattr(self.rule, 'name', 'rule')}): {err}"
        self.history.append({"step": failed, "wall_s": run.at.wall, "loss": math.nan, "rejected": message})
        run.state, run.at.step, note, stop = run.guard.reject(self.rule, run.state, run.model, run.at.step,
                                                              failed, getattr(err, "overshoot", None))
        if stop:
            bar.close()
            raise NonFiniteError(f"{message}; {stop}; {self._last_good(run)}") from None
        if self.parallel.is_writer:
            warnings.warn(f"{message}; step rejected{note}", RuntimeWarning, stacklevel=4)

    def _check_stop(self, run: _Run, record: dict) -> None:
        """The stopping rule, every ``stop.every`` accepted steps (its time counts as training)."""
        at = run.at
        if run.stop_state is None or at.step % self.stop.every:
            return
        t0 = time.perf_counter()
        run.stop_state, checked, fired = self.stop.check(run.stop_state, run.model)
        at.wall += time.perf_counter() - t0
        record.update(checked)
        if fired:
            at.stopped_by = self.stop.name

    def _after(self, run: _Run, record: dict) -> bool:
        """Evaluation, history, callbacks and checkpoint after an accepted step; True when done."""
        at = run.at
        done = self._done(at)
        if at.step % self.eval_every == 0 or done or at.step == 1:
            record.update(self.evaluate(run.model, run.test))
            self._check_evaluation(record["y_err"], run.at.y_err0)
        run.guard.accept(at.step)
        self.history.append(record)
        for cb in self.callbacks:
            if cb(record, run.model) and not done:
                done, at.stopped_by = True, "callback"
        if self.parallel.agree(done) and not done:  # e.g. another process's time budget ran out
            done, at.stopped_by = True, "another process"
        if done and "y_err" not in record:  # a callback stopped between evaluations
            record.update(self.evaluate(run.model, run.test))
        if self.parallel.is_writer and self.checkpoint is not None and (
                done or at.step % self.checkpoint.every == 0):
            self._save(run)
        return done

    def _check_evaluation(self, y_err: float, start: float) -> None:
        """Reject the step just taken when its test predictions are not finite, or their relative
        y-error exceeds ``√max_loss_growth`` times that of the network training started from (at
        least 1, a zero network's; the loss is its square): the loss-growth guard judges an update
        only at the next step, and the last step has none."""
        growth = math.inf if self.max_loss_growth is None else math.sqrt(self.max_loss_growth)
        bound = growth * max(start, 1.0)
        if not math.isfinite(y_err) or y_err > bound:
            err = NonFiniteError(f"the network's test y-error after this step is {y_err:.3g} (at the start "
                                 f"{start:.3g}, the bound {bound:.3g}): its update blew up; it is undone "
                                 f"({ADVICE})")
            err.overshoot = bound / y_err if math.isfinite(y_err) else None
            raise err

    def fit(self) -> Result:
        run = self._start()
        bar = _progress(self.steps, self.progress if self.parallel.is_writer else False, run.at.step)
        done = self._done(run.at)  # a resumed run that had already finished
        while not done:
            info = self._step(run, self._batch(run), bar)
            if info is None:
                continue
            record = {"step": run.at.step, "wall_s": run.at.wall, **info}
            self._check_stop(run, record)
            try:
                done = self._after(run, record)
            except NonFiniteError as err:  # rejected after the fact (a finite blow-up: cut by its overshoot)
                run.at.stopped_by = None
                self._reject(run, err, bar, failed=run.at.step)
                continue
            bar.update(1)
            bar.set_postfix(loss=f"{info['loss']:.3g}", refresh=False)
        bar.close()
        return Result(run.model, self.history, self._metrics(run), run.state)

    def _metrics(self, run: _Run) -> dict:
        last, at = self.history[-1], run.at
        metrics = {
            "problem": getattr(self.problem, "name", None), "method": getattr(self.rule, "name", None),
            "steps": at.step, "wall_s": at.wall, "x_err": last.get("x_err"), "y_err": last["y_err"],
            "loss": last["loss"], "step_s": at.wall / at.step, "n_train": self.n_train,
            "n_test": self.n_test, "batch_size": self.batch_size, "seed": self.seed,
            "world_size": self.parallel.world_size, "device": str(self.device),
            "n_params": sum(p.numel() for p in run.model.parameters() if p.requires_grad),
            "rejected_steps": sum(1 for h in self.history if "rejected" in h),
            "stopped_by": at.stopped_by or ("steps" if self.steps is not None and at.step >= self.steps
                                            else "time_budget"),
        }
        if self._own is not None:
            metrics["data"] = {"rows": self._own["rows"], "x": self._own["x_test"] is not None,
                               "model_mismatch": self._own["model_mismatch"],
                               "split": "in order: first rows train, then the stopping rule's rows, "
                                        "the last n_test rows test"}
        if run.stop_state is not None:
            metrics["stop_rule"] = {"name": self.stop.name, **self.stop.describe(run.stop_state)}
        if self._target_info is not None:
            metrics["target"] = self._target_info
        return metrics


def _progress(total, enabled, initial=0):
    """tqdm on an interactive terminal; silent when not a TTY, under CI, or if disabled."""
    from tqdm.auto import tqdm

    if enabled is None:
        enabled = sys.stderr.isatty() and not os.environ.get("CI")
    return tqdm(total=total, initial=initial, disable=not enabled, unit="step", leave=False)


def train(problem, rule, model=None, **kw) -> Result:
    """``Trainer(problem, rule, model, **kw).fit()``."""
    return Trainer(problem, rule, model, **kw).fit()
