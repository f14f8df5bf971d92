"""The common trainer: one loop for every update rule (no ``if method == ...``). Per step it records
the batch y-loss (``½ · mean_i ‖P(f(y*_i)) − y*_i‖²``, Euclidean) and the training wall time (steps only,
not evaluations: runs compare at equal wall-clock time); every ``eval_every`` steps the test errors
(:mod:`pdeinv.training.evaluation`). It composes :mod:`pdeinv.training.trainset` (data),
:mod:`pdeinv.methods.guard`,
:mod:`pdeinv.training.stopping`, :mod:`pdeinv.training.checkpoint` and :mod:`pdeinv.training.distributed`.
"""

from __future__ import annotations

import logging
import math
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, fields

import torch

from .._checks import count, positive
from ..methods.base import NonFiniteError, UpdateRule
from ..methods.guard import Guard
from ..methods.presets import PRESET, run_defaults
from ..methods.protocol import declared
from ..physics.backends.device import placed, resolve
from ..posterior.stage import CalibrationStage
from ..posterior.stage import stage as calibration_stage
from ..problem.definition import Problem
from ..problem.trained import mark_trained
from ..problem.units import in_units
from ..util.progress import progress
from . import arguments as args
from . import checkpoint as ckpts
from .checkpoint import Checkpoint, Position
from .data import OwnData, own_data
from .distributed import Single
from .evaluation import check_evaluation, evaluate, metrics
from .plan import PriorStage
from .stopping import STILL_STEPS, at_rounding, converged, finished, parameters
from .trainset import (
    BATCH_ORDER,
    CALIBRATION_DATA,
    N_TRAIN,
    fit_inputs,
    fresh_rows,
    seed_stream,
    stop_rows,
    test_count,
    test_rows,
    training_fields,
    training_rows,
)
from .verdict import of_predictions

__all__ = ["Callback", "Result", "Trainer", "seed_stream", "train"]

#: ``callback(record, model) -> bool | None``; returning True stops training after this step
Callback = Callable[[dict, torch.nn.Module], "bool | None"]


@dataclass
class Result:
    """A finished run: the trained model, the per-step history, the final metrics and rule state."""

    model: torch.nn.Module
    history: list[dict]
    metrics: dict
    state: object = None
    posterior: object = None  # a pdeinv.posterior.conformal.Calibration from the calibration stage, or None


@dataclass
class _Run:
    """One fit's live objects: the model, the rule state, the data, the stopping rule's state."""

    model: torch.nn.Module
    state: object
    y_train: torch.Tensor
    t_train: torch.Tensor | None  # what P f(y) must match (float64) if not y_train (pdeinv.methods.targets)
    test: tuple
    stop_state: object
    at: Position
    guard: Guard  # step size, failures, lowest loss, last good state (methods.guard)
    still: int = 0  # accepted steps in a row that moved no parameter (stopping.converged)
    columns: ckpts.HistoryColumns = field(default_factory=ckpts.HistoryColumns)  # the saved history

    def batch(self, size: int, n: int) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The next ``size`` training rows and their float64 targets (``None``: the rows); all: themselves."""
        rows, y, t = self.at.next_rows(size, n), self.y_train, self.t_train
        return (y, t) if size == n else (y[rows], None if t is None else t[rows])


#: the settings :meth:`Trainer.fit` checks again, which may change between construction and ``fit()``
COUNTS = ("steps", "time_budget", "n_train", "n_test", "batch_size", "eval_every", "seed")


def _same_number(a, b) -> bool:
    """``a == b`` for plain numbers and strings (``trainer.max_failures = 5`` again is no change)."""
    plain = (bool, int, float, str, type(None))
    return type(a) in plain and type(b) in plain and a == b


@dataclass
class Trainer:
    """Train ``model`` on ``problem`` with ``rule`` (a :class:`~pdeinv.methods.GD`, ``SIP``, ``HIG``, …).

    **Data** (:mod:`pdeinv.training.trainset`): ``n_train`` and ``n_test`` independent seeded draws of
    ``problem.sample``, or the user's rows ``data`` (numpy ``(B, m)``, tensor or torch ``Dataset``;
    ``data_x`` ``(B, N)``, optional, only for ``x_err``): the last ``n_test`` rows test, the stopping
    rule's ``stop.n_val`` before them, the rest train (:func:`pdeinv.training.data.own_data`). Batches are
    drawn
    without replacement, reshuffled every epoch (``batch_size=None``: every training row in order, each
    step). ``fresh=True`` (the SIP paper's protocol) trains each step on ``batch_size`` new draws of the
    scene's prior instead (:func:`~pdeinv.training.trainset.fresh_rows`, seeded per step; their ``x``
    enters no loss); the ``n_train`` rows then only fit the input transform and the target.
    ``model=None`` takes ``problem.model()`` after ``torch.manual_seed(seed)`` (with the preset's
    ``rows_per_component`` for gd and adam, as ``pdeinv train``); ``fit_scaling`` fits its
    input transform on the training observations at the problem's noise level (never on ``x``).

    **Arguments.** ``problem`` is a :class:`~pdeinv.Problem` or a name / module path (loaded with
    :func:`~pdeinv.load_problem`); ``rule`` an update rule or a method name (``"sip"``, ``"gd"``,
    ``"adam"``, ``"hig"``, ``"supervised"``: :func:`pdeinv.methods.presets.make_rule`, the CLI's
    ``--method``); ``stop`` a stopping rule, ``None`` or a name as ``pdeinv train --stop`` takes it
    (default ``"auto"``: :func:`pdeinv.training.stopping.chosen`, the CLI's default; ``None``: only
    ``steps``, ``time_budget`` and the rule's fixed point end the run); ``checkpoint`` a
    :class:`~pdeinv.Checkpoint` or a path. Every argument is checked here: a wrong kind of object is a
    ``TypeError``, a wrong value a ``ValueError``, each naming the argument and what is allowed.

    **Presets.** ``steps`` and ``batch_size`` left at ``"preset"`` come from the rule's preset, the
    table ``pdeinv train --method`` reads (:data:`pdeinv.methods.presets.GENERIC`,
    :func:`~pdeinv.methods.presets.run_defaults`): sip 30 full-batch steps, hig 1000 full-batch steps
    (batch 32 on an MLP), gd and adam 1000 steps of 32, supervised 10 full-batch steps; a rule not in
    the table 1000 steps of 32. With ``time_budget`` and no ``steps``, the budget alone ends the run.

    Stops after ``steps`` steps or ``time_budget`` seconds of training,
    when a callback returns True, or when the stopping rule ``stop`` fires (e.g.
    :class:`~pdeinv.training.stopping.DiscrepancyStop`, every ``stop.every`` accepted steps, on held-out
    observations only), or at the rule's fixed point (two steps in a row that moved no parameter, at a
    rounding-level loss: :func:`~pdeinv.training.stopping.converged`). ``metrics["stopped_by"]`` says
    which (``steps``, ``time_budget``, the rule's name, ``converged`` or ``callback``) and
    ``metrics["steps"]`` at which step.

    **Guard** (:class:`~pdeinv.methods.guard.Guard`: its policy, budget and messages). A step whose loss,
    prediction or update holds NaN/Inf, whose loss exceeds ``max_loss_growth`` (1e3; None: off) times the
    lowest accepted one, or whose test predictions blow up is *rejected* (a ``history`` row with ``loss``
    NaN and the message under ``rejected``, and a warning): the last good state (copied every
    ``snapshot_every`` steps; 1: the step before) is put back, the step size cut by ``step_factor`` (½;
    back toward 1 after ``recover_after`` clean steps). ``max_failures`` rejections in a row, or one at
    the floor ``min_scale``, raise :class:`NonFiniteError`.

    **Checkpoints.** ``checkpoint=Checkpoint(path, every=k)`` saves the run atomically every ``k``
    accepted steps and after the last (:mod:`pdeinv.training.checkpoint`: what it holds; a resumed run repeats
    the uninterrupted one bitwise, HIG's kept-rows route to rounding). ``resume=True`` continues from
    it (``FileNotFoundError`` if there is none; ``ValueError`` if it belongs to another problem,
    network, rule, configured hyper-parameter or data setting, or ``steps`` is below its step);
    ``steps`` and ``time_budget`` may grow on resume. Wall time spent after the last save is not counted.

    ``device`` (default ``"cpu"``): the model and the training data are moved there, and a dense, modal
    or SVD physics backend is applied there by torch (:mod:`pdeinv.physics.backends.device`; time stepping
    stays
    on the CPU). An unknown device, or CUDA where there is none, is a ``ValueError``.

    **Stages.** The rule's stage is the loop above. Then, where the network has a part fitted on the prior
    (:class:`~pdeinv.nets.refine.PriorFitted`: the default network's correction and data-consistency
    layer), ``prior`` (a :class:`~pdeinv.training.plan.PriorStage`; ``"auto"``: the default one, as
    ``pdeinv train``; ``None``: none) fits it on draws of the scene's prior, or on own data's training rows
    when they carry ``x``, unless it decides beforehand that it cannot help (and says why).
    Last, ``calibration`` (a :class:`~pdeinv.posterior.CalibrationStage`; ``"auto"``: the default one;
    ``None``: none) gives the network a split-conformal posterior from held-out prior draws
    (``result.posterior``; its checks on the test rows in ``metrics["posterior"]``).
    ``metrics["stages"]`` lists each stage with its held-out ``x_err``, ``y_err``, steps and seconds.

    **Data parallel.** ``parallel`` (:class:`~pdeinv.training.distributed.Single`, or
    :class:`~pdeinv.training.distributed.DataParallel` from torchrun's environment by
    :func:`pdeinv.training.distributed.from_env`) shards each *global* batch (``batch_size``, divisible by the
    number of processes) and averages the rule's direction and loss; all ranks agree on every stop and
    rejection; only rank 0 saves checkpoints, warns and shows progress. ``metrics["world_size"]``.
    """

    problem: Problem | str | os.PathLike  # a name / module path is loaded (load_problem)
    rule: UpdateRule | str  # a method name is built with its preset (methods.presets.make_rule)
    model: torch.nn.Module | None = None
    steps: int | None | str = "preset"  # "preset": the rule's (presets.run_defaults); None: time_budget only
    time_budget: float | None = None
    n_train: int = N_TRAIN
    n_test: int | None = None  # None: 256 draws of the scene, 128 rows of own data (trainset.test_count)
    batch_size: int | None | str = "preset"  # None: every training row in each step (full batch)
    seed: int = 0
    eval_every: int = 50
    fit_scaling: bool = True
    stop: object | str | None = "auto"  # a stopping rule (.stopping), None, or a name: "auto", "plateau", …
    target: object = "auto"  # what P f(y) must match (pdeinv.methods.targets): "auto", None or a strategy
    callbacks: list[Callback] = field(default_factory=list)
    progress: bool | None = None
    dtype: torch.dtype | None = None  # None: the model's own parameter dtype (float32 for the default MLP)
    checkpoint: Checkpoint | str | os.PathLike | None = None  # a path: Checkpoint(path)
    resume: bool = False
    max_failures: int = 5
    step_factor: float = 0.5
    max_loss_growth: float | None = 1e3
    min_scale: float = 1e-12
    recover_after: int | None = 50
    snapshot_every: int = 10
    device: str | torch.device = "cpu"
    data: object = None  # own observations (B, m): array, tensor or torch Dataset
    data_x: object = None  # their true fields (B, N), for errors only
    accept_bad: bool = False  # train on data whose y the noise does not explain (the CLI's --accept-bad)
    parallel: object = field(default_factory=Single)  # pdeinv.training.distributed: Single or DataParallel
    prior: PriorStage | None | str = "auto"  # the stage after the rule's (pdeinv.training.plan)
    fresh: bool = False  # each step's batch: new draws of the scene's prior (the SIP paper's protocol)
    calibration: CalibrationStage | None | str = "auto"  # the last stage: the posterior (posterior.stage)
    history: list[dict] = field(default_factory=list, init=False)
    _target_info: dict | None = field(default=None, init=False, repr=False)
    _target_of: Callable | None = field(default=None, init=False, repr=False)  # fresh rows' targets
    _own: OwnData | None = field(default=None, init=False, repr=False)
    _saved_step: int | None = field(default=None, init=False, repr=False)
    _rule: object = field(default=None, init=False, repr=False)
    _preset: dict = field(default_factory=dict, init=False, repr=False)
    _batch_preset: bool = field(default=False, init=False, repr=False)  # batch_size was the preset's
    _given: dict = field(default_factory=dict, init=False, repr=False)  # the settings as checked
    #: seconds of each set-up phase of the last :meth:`fit` (``metrics["setup"]``): network (when built
    #: here), samples (training and test draws), fit (input transform and target), rule (its state and
    #: calibration), stop (the stopping rule's held-out draws)
    setup: dict = field(default_factory=dict, init=False)
    setup_cpu: dict = field(default_factory=dict, init=False)  # the same phases in CPU seconds

    def __post_init__(self):
        self._check_arguments()
        if self.steps is None and self.time_budget is None:
            raise ValueError("give steps=, time_budget= or both; otherwise training never stops")
        self.steps = None if self.steps is None else count(self.steps, "steps")
        self.time_budget is None or positive(self.time_budget, "time_budget")
        self.n_test = count(test_count(self.n_test, self.data is not None), "n_test")
        if self.data is None and self.data_x is not None:  # it was ignored: the run trained on prior draws
            raise ValueError("data_x= was given without data=: data_x holds the true fields of the rows of "
                             "data= (for the errors only); pass the observations as data= too, or drop it")
        if self.data is not None:
            if self.n_train != N_TRAIN:  # it would be ignored: the data's rows are the training rows
                raise ValueError(f"n_train={self.n_train!r} does not apply with data=: every row of the "
                                 "data not held out (n_test, the stopping and calibration rows) trains; drop "
                                 "n_train, or pass fewer rows")
            self._own = own_data(self.problem, self.data, self.data_x, self.n_test,
                                 self.stop.n_val if self.stop is not None else 0, self.parallel.is_writer,
                                 self.calibration, accept_bad=self.accept_bad)
            self.n_train = len(self._own.y)
            if self.fresh:
                raise ValueError("fresh=True draws new observations of the scene's prior each step; data= "
                                 "gives fixed rows: drop one of them")
        if self.fresh and self.rule.needs_fields:  # before any draw: the target exists for fixed rows only
            raise ValueError(f"rule {self.rule.name!r} fits the true fields x of its training rows, and "
                             "fresh=True (--fresh-draws) trains on new observations whose x no loss sees: "
                             "drop fresh, or use a physics-based rule (sip, adam, gd, hig)")
        self.n_train = count(self.n_train, "n_train", minimum=2)  # the CLI's --n-train range: whitening
        self.batch_size = self.n_train if self.batch_size is None else count(self.batch_size, "batch_size")
        if self._batch_preset:  # gd's 32 rows on 16 training rows: all of them, not a refusal
            self.batch_size = min(self.batch_size, self.n_train)
        if self.batch_size > self.n_train and self.fresh is not True:  # fresh: n_train rows fit the scaling
            b, n = self.batch_size, self.n_train
            if self.data is None:
                raise ValueError(f"batch_size={b} is larger than n_train={n}; expected batch_size <= {n}")
            raise ValueError(f"batch_size={b} (--batch-size) is larger than the {n} training rows of data "
                             f"(its rows less n_test={self.n_test} (--n-test) and the other held-out rows); "
                             f"expected at most {n}")
        self.eval_every = count(self.eval_every, "eval_every")
        self._guard()  # checks its settings
        if self.resume and self.checkpoint is None:
            raise ValueError("resume=True needs checkpoint=Checkpoint(path) to resume from")
        ck = self.checkpoint
        if not self.resume and ck is not None and not ck.overwrite and ck.exists():
            raise ValueError(f"checkpoint {str(ck.path)!r} holds another run's checkpoint: resume=True "
                             f"continues it, Checkpoint({str(ck.path)!r}, overwrite=True) replaces it; or "
                             "choose another path")
        self.device = resolve(self.device)
        self.parallel.check_batch(self.batch_size)
        self._rule = self.parallel.rule(self.rule)  # the rule on this process's shard
        self._given = self._settings()

    def _settings(self) -> dict:
        """The constructor's arguments other than the counts (which :meth:`_counts` checks again), as
        checked and turned into objects: an attribute set after that is refused by :meth:`fit`."""
        return {f.name: vars(self)[f.name] for f in fields(self) if f.init and f.name not in COUNTS}

    def _check_arguments(self) -> None:
        """The kinds of the arguments (:mod:`pdeinv.training.arguments`), names turned into objects, and the
        rule's preset for ``steps`` / ``batch_size`` left at ``"preset"``."""
        self.problem = args.problem(self.problem, type(self).__name__)
        # a name or a rule object, then what it can do, declared once (pdeinv.methods.protocol)
        self.model = args.fits(args.model(self.model), self.problem)
        self.parallel = args.parallel(self.parallel)
        self.target = args.target(self.target)
        self.rule = declared(args.rule(self.rule, self.problem, self.model))
        self.seed = args.seed(self.seed)
        self.checkpoint = args.checkpoint(self.checkpoint)
        self.callbacks = args.callbacks(self.callbacks)
        self.dtype = args.dtype(self.dtype)
        self.fit_scaling = args.flag(self.fit_scaling, "fit_scaling")
        self.resume = args.flag(self.resume, "resume")
        self.accept_bad = args.flag(self.accept_bad, "accept_bad")
        self.progress = args.flag(self.progress, "progress", optional=True)
        self.prior = args.prior(self.prior)
        self.fresh = args.flag(self.fresh, "fresh")
        self.calibration = calibration_stage(self.calibration)
        self._preset = run_defaults(self.rule, self.model, self.problem)
        if self.steps == PRESET:
            self.steps = None if self.time_budget is not None else self._preset["steps"]
        # "auto": the CLI's --stop auto for these steps and this network (None: the default one)
        self.stop = args.stop(self.stop, self.problem, self.steps, self.model)
        if self.batch_size == PRESET:  # the preset's rows per step, at most the training rows (below)
            self.batch_size, self._batch_preset = self._preset["batch_size"], True

    def _data(self):
        """``(y_train numpy, y_train torch, (x_test, y_test numpy, y_test torch))`` on ``device``."""
        y = training_rows(self.problem, self._own, self.n_train, self.seed)
        xt, yt = test_rows(self.problem, self._own, self.n_test, self.seed)
        t = lambda a: torch.as_tensor(a, dtype=self.dtype or torch.float32, device=self.device)  # noqa: E731
        return y, t(y), (xt, yt, t(yt))

    def held_out(self) -> tuple:
        """The test set ``(x or None, y)`` as numpy: own data's last rows (in the data's units), or the
        seeded samples."""
        x, y = test_rows(self.problem, self._own, self.n_test, self.seed)
        c = self._units
        return (None if x is None else x * c, y * c) if c != 1.0 else (x, y)

    @property
    def _units(self) -> float:
        """What own data was divided by (:mod:`pdeinv.problem.units`); 1 for prior draws."""
        return 1.0 if self._own is None else self._own.units

    def evaluate(self, model, test) -> dict:
        """Mean relative L²(Ω) errors on ``test`` (:func:`pdeinv.training.evaluation.evaluate`)."""
        return evaluate(self.problem, model, test)

    def identity(self, model) -> dict:
        """What a checkpoint must share with this run to be resumed by it
        (:mod:`pdeinv.training.checkpoint`)."""
        return ckpts.run_identity(self.problem, self.rule, model, {
            "seed": self.seed, "n_train": self.n_train, "n_test": self.n_test, "batch_size": self.batch_size,
            "dtype": str(self.dtype),
            "target": self.target if self.target is None or self.target == "auto" else self.target.name,
            **({} if self._own is None else {"data": self._own.fingerprint}),
            **({"fresh": True} if self.fresh else {})})

    def _network_settings(self) -> dict:
        """``problem.model``'s settings: with own data, the linear part takes nothing from the scene's
        sampler where it can (:func:`pdeinv.nets.data_base`)."""
        if self.problem.model_factory is not None:
            return {}
        cap = self._preset.get("rows_per_component")
        settings = {} if cap is None else {"rows_per_component": cap}  # the preset's (presets.GENERIC)
        if self._own is None:
            return settings
        from ..nets import data_base

        return {**settings, "base": data_base(self.problem)}

    def _guard(self) -> Guard:
        return Guard(self.max_failures, self.step_factor, self.max_loss_growth, self.min_scale,
                     self.recover_after, self.snapshot_every)

    def _start(self) -> _Run:
        """Model on ``device``, data, preconditioning, rule and stopping states, batch order; resumed."""
        clock, cpu, self.setup, self.setup_cpu = time.perf_counter(), time.process_time(), {}, {}

        def lap(phase):  # wall and CPU seconds: on a shared machine the wall clock counts the others' jobs
            nonlocal clock, cpu
            now, now_cpu = time.perf_counter(), time.process_time()
            self.setup[phase] = self.setup.get(phase, 0.0) + now - clock
            self.setup_cpu[phase] = self.setup_cpu.get(phase, 0.0) + now_cpu - cpu
            clock, cpu = now, now_cpu

        if self.model is None:
            torch.manual_seed(self.seed)
            settings = self._network_settings()
            self.model = self.problem.model(**settings)
            # what rebuilds it: pdeinv.save_run's default network_spec (a data file's base is another)
            self.model.network_spec = {"kind": "default", **settings}
            lap("network")
        mark_trained(self.model, self.problem)  # save_run, predict: not with another of the same size
        first = next(iter(self.model.parameters()), None)
        self.dtype = self.dtype or (torch.float32 if first is None else first.dtype)
        model = self.model.to(device=self.device, dtype=self.dtype)
        if self.checkpoint is not None:
            ckpts.check_resumable(self.rule)
        y_np, y_train, test = self._data()
        lap("samples")
        fields = lambda: training_fields(self.problem, self._own, self.n_train, self.seed)  # noqa: E731
        t_train, self._target_info, self._target_of = fit_inputs(
            self.problem, self.rule, self.target, model, y_np, y_train, self.fit_scaling, fields)
        lap("fit")
        stop_state = None if self.stop is None else self.stop.init(
            self.problem, y_np, stop_rows(self.problem, self._own, self.stop.n_val, self.seed))
        lap("stop")
        self.parallel.check_same("run", lambda: {
            **self.identity(model), "steps": self.steps, "time_budget": self.time_budget,
            "eval_every": self.eval_every, "resume": self.resume,
            "stop": None if self.stop is None else self.stop.name})
        gen = torch.Generator().manual_seed(seed_stream(self.seed, BATCH_ORDER))
        run = _Run(model, self._rule.init(placed(self.problem, self.device), model), y_train, t_train, test,
                   stop_state, Position(gen, torch.randperm(self.n_train, generator=gen)), self._guard())
        # e.g. SIP's proxy curvature, on the first batch (a no-op for a rule that measures nothing); fresh
        # draws: on rows of the prior (sub-stream 0, no step's), as every step's batch: n_train rows whiten
        # the input, and 64 rows of 15 underestimate a direction's variance up to 3.7× (Marchenko–Pastur),
        # which a curvature measured on those same rows never sees
        first = self._fresh(0)[0] if self.fresh else y_train[run.at.order[:self.batch_size]]
        run.state = self._rule.calibrate(run.state, model, first)
        lap("rule")
        self.history = []
        if self.resume:
            saved = ckpts.load_to_resume(self.checkpoint, self.identity(model), self.steps)
            run.state = ckpts.restore(saved, model, self.rule, run.state, run.at, run.guard)
            self.history, self._saved_step = ckpts.history_rows(saved["history"]), run.at.step
        if run.at.y_err0 is None:  # a fresh run (a resumed one keeps its starting point's)
            start = self.evaluate(model, test)["y_err"]
            run.at.y_err0 = start if math.isfinite(start) else 1.0
        lap("evaluate")
        return run

    def _reject(self, run: _Run, err: NonFiniteError, bar, failed: int) -> None:
        """Record rejected step ``failed``; the guard rolls back and lowers the step size, or stops."""
        message = f"step {failed} ({self.rule.name}): {err}"
        self.history.append({"step": failed, "wall_s": run.at.wall, "loss": math.nan, "rejected": message})
        run.state, run.at.step, note, stop = run.guard.reject(self.rule, run.state, run.model, run.at.step,
                                                              failed, err.overshoot)
        if stop:
            bar.close()
            where = ckpts.last_good(run.guard.good.step, self.checkpoint, self._saved_step)
            raise NonFiniteError(f"{message}; {stop}; {where}") from None
        if self.parallel.is_writer:
            warnings.warn(f"{message}; step rejected{note}", RuntimeWarning, stacklevel=4)

    def _after(self, run: _Run, record: dict, before) -> bool:
        """Stopping rule (its time counts), the fixed point (``before``: the parameters before the step),
        evaluation, history, callbacks, checkpoint; True when done."""
        at = run.at
        if run.stop_state is not None and at.step % self.stop.every == 0:
            t0, (run.stop_state, checked, fired) = time.perf_counter(), self.stop.check(run.stop_state,
                                                                                        run.model)
            at.wall, at.stopped_by = at.wall + time.perf_counter() - t0, self.stop.name if fired else None
            record.update(checked)
        first = self.history[0]["loss"] if self.history else record["loss"]
        m = self.problem.operator.n_out
        still = at_rounding(record["loss"], first, m) and converged(  # copies the parameters only then
            before, parameters(run.model), record["loss"], first, m)
        run.still = run.still + 1 if still else 0
        if at.stopped_by is None and run.still >= STILL_STEPS:
            at.stopped_by = "converged"  # at a fixed point (pdeinv.training.stopping)
        done = finished(at, self.steps, self.time_budget)
        if at.step % self.eval_every == 0 or done or at.step == 1:
            record.update(self.evaluate(run.model, run.test))
            check_evaluation(record["y_err"], run.at.y_err0, self.max_loss_growth)
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
            ckpts.save(self.checkpoint, self.identity(run.model), run.model, self.rule, run.state, at,
                       run.guard, self.history, run.columns)
            self._saved_step = at.step
        return done

    def _counts(self) -> None:
        """The counts checked again as :meth:`fit` starts: an attribute set after construction
        (``trainer.steps = -5``) ran one step; any other setting set after construction is refused."""
        self.steps is None or count(self.steps, "steps")
        self.time_budget is None or positive(self.time_budget, "time_budget")
        count(self.n_test, "n_test"), count(self.eval_every, "eval_every")
        count(self.batch_size, "batch_size")
        self.seed = args.seed(self.seed)
        now = self._settings()
        changed = [k for k, v in now.items() if v is not self._given[k]
                   and not _same_number(v, self._given[k])]
        if changed:  # names became objects, data was checked and split: once, as the Trainer was built
            k = changed[0]
            raise ValueError(f"trainer.{k} was set after construction ({k}={now[k]!r:.60}): the Trainer "
                             "checks its settings when it is built (own data split, names made objects); "
                             f"pass it as Trainer(..., {k}=...)")
        if count(self.n_train, "n_train", minimum=2) < self.batch_size and self.fresh is not True:
            raise ValueError(f"batch_size={self.batch_size} is larger than n_train={self.n_train}; expected "
                             f"batch_size <= {self.n_train}")

    def fit(self) -> Result:
        self._counts()
        run = self._start()
        self._given = self._settings()  # the network it built, the dtype it chose: a second fit() keeps them
        bar = progress(self.steps, self.progress if self.parallel.is_writer else False, run.at.step)
        done = finished(run.at, self.steps, self.time_budget)  # a resumed run that had finished
        while not done:
            at, t0 = run.at, time.perf_counter()
            batch = self._fresh(at.step + 1) if self.fresh else run.batch(self.batch_size, self.n_train)
            before = parameters(run.model)
            try:  # one guarded step
                run.state, info = run.guard.step(self._rule, run.state, run.model, *batch)
            except NonFiniteError as err:  # rejected: last good state back, step size lowered
                at.wall += time.perf_counter() - t0
                self._reject(run, err, bar, at.step + 1)
                continue
            at.wall += time.perf_counter() - t0
            at.step += 1
            try:
                done = self._after(run, {"step": at.step, "wall_s": at.wall, **info}, before)
            except NonFiniteError as err:  # rejected after the fact (a finite blow-up: cut by its overshoot)
                at.stopped_by = None
                self._reject(run, err, bar, at.step)
                continue
            bar.update(1)
            bar.set_postfix(loss=f"{info['loss']:.3g}", refresh=False)
        bar.close()
        if "y_err" not in self.history[-1]:  # resumed past its budget: its last step was not evaluated
            self.history[-1].update(self.evaluate(run.model, run.test))
        stages = [self._rule_stage(run)]
        if self.prior is not None and self.prior.applies(run.model):
            stages.append(self._prior_stage(run))
        posterior = None
        if self.calibration is not None:
            posterior, info = self.calibration.run(self.problem, run.model, self._own, self.seed, run.test,
                                                   self._calibration_rows)
            stages.append(info)
        record = metrics(self, run)
        record["stages"] = stages
        if posterior is not None and "test" in stages[-1]:
            record["posterior"] = stages[-1]["test"]
        record["unseen_energy"], warning = of_predictions(self.problem, run.model, run.test, self.seed)
        if warning and self.parallel.is_writer:  # energy where the physics cannot see (.verdict)
            warnings.warn(warning, RuntimeWarning, stacklevel=2)
        model, posterior = in_units(run.model, posterior, record, self._units)
        return Result(model, self.history, record, run.state, posterior)

    def _say(self, line: str) -> None:
        """What a stage is doing, for whoever listens (logger ``"pdeinv"``, INFO: the CLI's progress
        lines, after the running command's name; silent with ``--quiet`` and for Python users who did not
        configure logging)."""
        if self.parallel.is_writer:
            logging.getLogger("pdeinv.progress").info(line)

    def _calibration_rows(self, n: int):
        """The calibration stage's ``n`` held-out prior pairs: stream ``CALIBRATION_DATA`` of the seed."""
        self._say(f"calibration stage: drawing {n} held-out prior pairs")
        return self.problem.sample(n, seed_stream(self.seed, CALIBRATION_DATA))

    def _fresh(self, step: int) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Step ``step``'s batch of new prior draws and its target (:func:`~.trainset.fresh_rows`)."""
        y = fresh_rows(self.problem, self.batch_size, self.seed, step)
        return (torch.as_tensor(y, dtype=self.dtype, device=self.device), self._target_of(y))

    def _rule_stage(self, run: _Run) -> dict:
        """The rule's stage as ``metrics["stages"]`` reports it: its steps, seconds and held-out errors."""
        last = self.history[-1] if self.history else self.evaluate(run.model, run.test)
        done = self.steps is not None and run.at.step >= self.steps
        by = run.at.stopped_by or ("steps" if done else "time_budget")
        data = {"data": "fresh", "draws": run.at.step * self.batch_size} if self.fresh else {}
        return {"name": self.rule.name, "steps": run.at.step, "seconds": run.at.wall, "stopped_by": by,
                **data, **{k: last[k] for k in ("x_err", "y_err") if k in last}}

    def _prior_stage(self, run: _Run) -> dict:
        """The prior stage (:class:`~pdeinv.training.plan.PriorStage`) after the rule's: decided on, run,
        and reported with the refined network's test errors; its time counts as training time."""
        stage, t0 = self.prior, time.perf_counter()
        why = stage.why_not(self.problem, run.model, self._own, self.seed, self.problem.relative_error,
                       log=self._say)
        if why is not None:
            return {"name": stage.name, "kept": False, "skipped": why, "seconds": time.perf_counter() - t0}
        info = stage.run(self.problem, run.model, self._own, self.seed, log=self._say)
        run.at.wall += time.perf_counter() - t0
        errors = {}
        if info.get("kept"):  # the run's last record: the refined network's test errors
            errors = self.evaluate(run.model, run.test)
            self.history[-1] = {**self.history[-1], **errors, "wall_s": run.at.wall}
        return {"name": stage.name, **info, **errors, "seconds": time.perf_counter() - t0}


def train(problem: Problem | str | os.PathLike, rule: UpdateRule | str, model: torch.nn.Module | None = None,
          **kw) -> Result:
    """Train ``model`` (default: ``problem.model()``) on ``problem`` with ``rule``; returns a
    :class:`Result` (``.model``, ``.history``, ``.metrics`` with the held-out ``x_err`` and ``y_err``).

    ``Trainer(problem, rule, model, **kw).fit()``: every keyword and its default is :class:`Trainer`'s.
    ``problem`` may be a name (``train("heat_1d", "sip")``) and ``rule`` a method name; ``steps`` and
    ``batch_size`` default to the rule's preset, the one ``pdeinv train --method`` runs
    (:mod:`pdeinv.methods.presets`).
    """
    unknown = sorted(set(kw) - {f.name for f in fields(Trainer) if f.init})
    if unknown:
        hint = {"prior_fit": "prior=pdeinv.PriorStage(pdeinv.nets.refine.PriorFit(steps=N)), or prior=None "
                             "(the CLI's --prior-fit N / 0)",
                "lr": "the rule's own lr, e.g. pdeinv.SIP(lr=...)"}
        known = "; ".join(f"{k}: use {hint[k]}" for k in unknown if k in hint)
        raise TypeError(f"train() got {', '.join(unknown)}: not an argument of pdeinv.Trainer"
                        + (f" ({known})" if known else " (see help(pdeinv.Trainer))"))
    return Trainer(problem, rule, model, **kw).fit()
