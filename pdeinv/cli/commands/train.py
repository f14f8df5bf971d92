"""``pdeinv train``: train the default network on a problem and write its results to ``--out``."""

from __future__ import annotations

import errno
import json
import logging
import re
import sys
import time
import warnings
from pathlib import Path

from . import (
    FAILED,
    PLAIN_FLOAT,
    PLAIN_INT,
    BadData,
    UsageError,
    _checks,
    add_set_argument,
    build_problem,
    declare_ranges,
    no_cache,
    parse_sets,
    prepare_out,
    set_threads,
)

ORDER = 1


#: test samples a run writes to fields.vtu/png when --export-samples is not given (at most --n-test)
EXPORT_SAMPLES = 3


#: --stop's names, built as Python's ``Trainer(stop=name)`` (:func:`pdeinv.training.arguments.stop`): 'auto'
#: stops nonlinear runs on the held-out residual's plateau and noisy data by the discrepancy principle where
#: no denoised target regularizes it, and leaves other runs to --steps / --time-budget
#: (:func:`pdeinv.training.stopping.chosen`)
STOPS = ("auto", "discrepancy", "plateau", "none")


def _hidden(text: str) -> tuple[int, ...]:
    try:
        widths = tuple(int(w) for w in text.split(","))
    except ValueError:
        raise UsageError(f"--hidden {text!r} is not a comma-separated list of widths, e.g. 64,64") from None
    if not widths or min(widths) < 1:
        raise UsageError(f"--hidden {text!r}: widths must be integers >= 1")
    return widths


def _one_line(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"pdeinv train: warning: {message}", file=sys.stderr)


def _check_flags(args) -> Path:
    """Refuse conflicting flags, and an ``--out`` holding another run's files (without ``--resume`` or
    ``--overwrite``) or anything not a pdeinv run's (:func:`pdeinv.util.outpaths.run_folder`), before any
    work; the resolved ``--out``."""
    from pdeinv.io.runs import OUTPUTS
    from pdeinv.util.outpaths import run_folder

    out = run_folder(args.out, "--out", replace=args.overwrite or args.resume, outputs=OUTPUTS, create=False)
    _check_values(args)
    return out


def _check_values(args) -> None:
    """Refuse flags out of range or in conflict with each other: the run's checks, which ``--explain``
    makes too (a plan of a run that would be refused is no plan)."""
    if args.resume and args.overwrite:
        raise UsageError("--resume and --overwrite conflict: --resume continues the run in --out, "
                         "--overwrite deletes it; pass one of them")
    if args.checkpoint_every < 0:
        raise UsageError(f"--checkpoint-every {args.checkpoint_every} is not allowed; "
                         "expected an integer >= 1, or 0 for no checkpoints")
    if args.resume and args.checkpoint_every == 0:
        raise UsageError("--resume needs checkpoints; drop --checkpoint-every 0")
    if args.export_samples is not None and args.export_samples < 0:
        raise UsageError(f"--export-samples {args.export_samples} is not allowed; expected an integer >= 0")
    if args.n_train is not None and args.n_train < 2:
        raise UsageError(f"--n-train {args.n_train} is not allowed; expected an integer >= 2 (the whitening "
                         "fits a covariance)")
    if args.n_test is not None and args.n_test < 1:
        raise UsageError(f"--n-test {args.n_test} is not allowed; expected an integer >= 1")
    from pdeinv.training.trainset import test_count

    args.n_test = test_count(args.n_test, bool(args.data))  # the default: 256 draws, 128 rows of a file
    if args.batch_size is not None and args.n_train is not None and args.batch_size > args.n_train \
            and not args.fresh_draws:  # fresh draws: each step's rows are new, --n-train fits the scaling
        raise UsageError(f"--batch-size {args.batch_size} is larger than --n-train {args.n_train}; expected "
                         f"--batch-size <= {args.n_train}")
    if args.data is not None and not str(args.data).strip():
        raise UsageError("--data '' names no file; expected an .npz with y (B, m) (or drop --data to train "
                         "on the problem's own draws)")
    if args.data and args.n_train is not None:
        raise UsageError("--n-train does not apply with --data: the file's rows train, except the last "
                         "--n-test (and the stopping rule's) rows, which are held out")
    if args.data and args.fresh_draws:
        raise UsageError("--fresh-draws draws new observations of the scene's prior each step; --data gives "
                         "fixed rows: drop one of them")
    if args.hidden is not None and args.net != "default":
        raise UsageError(f"--net {args.net} and --hidden {args.hidden} choose two networks (--hidden is the "
                         "MLP's widths): drop one of them")


class _Heartbeat:
    """A callback that prints the run's plan with its first step (once the start-up checks have passed, so
    that a refused run says only why) and, when stderr is not a terminal (a log file, CI, ``nohup``), where
    tqdm's bar stays silent, one progress line with the first step (its estimate of the stage's time) and
    every ``every_s`` seconds after: a long run is never mute (a run once printed nothing for 580 s)."""

    def __init__(self, steps: int | None, plan=None, every_s: float = 60.0, lines: bool = True):
        self.steps, self.plan, self.every_s, self.lines = steps, plan, every_s, lines
        self.last, self.first = time.monotonic(), True
        self.since = None  # (clock, step) of the first line: what is left at the pace seen since then

    def __call__(self, record: dict, model) -> bool:
        log, now = logging.getLogger("pdeinv"), time.monotonic()
        if self.first and self.plan is not None:
            log.info(f"pdeinv train: {self.plan.summary()} (--explain: why)")
        if self.lines and (self.first or now - self.last >= self.every_s):
            self.last = now
            of = f"/{self.steps}" if self.steps else ""
            errs = "".join(f", {k} {record[k]:.4g}" for k in ("x_err", "y_err") if k in record)
            step, wall = record["step"], record["wall_s"]
            left = wall / step * (self.steps - step) if self.steps and 0 < step < self.steps else 0
            if self.since is None:
                self.since = (now, step)
            elif step > self.since[1] and self.steps and step < self.steps:  # checkpoints, checks included
                left = (now - self.since[0]) / (step - self.since[1]) * (self.steps - step)
            log.info(f"pdeinv train: step {step}{of}, loss {record['loss']:.4g}{errs}, {wall:.0f} s"
                     + (f", at most ~{left:.0f} s left in the rule's stage" if left >= 1 else ""))
        self.first = False
        return False


def cmd_train(args) -> int:
    """Train the default network; write metrics.json, history.csv, training.png, fields.vtu/png.

    Under torchrun (``WORLD_SIZE`` > 1) every process runs this with the same command line
    (checked); only rank 0 writes and reports, the others fail quietly with the same exit code
    (every check here runs identically on every rank, so rank 0's line speaks for all).
    """
    from pdeinv.io.runs import problem_spec
    from pdeinv.training.distributed import rank_from_env

    if str(args.problem).strip():  # what run.json records, read before a module's make() can chdir
        args.problem_spec = problem_spec(args.problem)
    if rank_from_env() == 0:
        return _train(args)
    from pdeinv.errors import numerical_types

    try:
        return _train(args)
    except numerical_types():
        return 1
    except (UsageError, ValueError, FileNotFoundError, NotImplementedError):
        return 2
    except BadData:
        return FAILED
    except KeyboardInterrupt as err:
        from pdeinv.cli.signals import exit_code

        return exit_code(err)


def _train(args) -> int:
    if args.explain:
        return _explain(args)
    if args.out is None:
        raise UsageError("--out DIR is required: the folder for the run's files (or --explain to see the "
                         "plan without training)")
    out = _check_flags(args)  # resolved: links and `..` taken (pdeinv.util.outpaths)
    new = not out.exists()
    try:
        code = _train_into(args, out)
    except BaseException:
        _remove_if_empty(out, new)
        raise
    if code:
        _remove_if_empty(out, new)
    return code


def _remove_if_empty(out: Path, new: bool) -> None:
    """A refused or failed run leaves no folder it created and wrote nothing into (its checkpoint's folder
    is made when the run is set up, before later checks)."""
    from pdeinv.util.outpaths import contents

    if new and out.is_dir() and not contents(out):
        for left in out.iterdir():  # a lock a killed run left, Finder's file (outpaths.IGNORED)
            left.unlink(missing_ok=True)
        out.rmdir()


def _train_into(args, out: Path) -> int:
    from pdeinv.training.distributed import from_env
    from pdeinv.training.verdict import FailedRun

    ckpt = out / "checkpoint.pt"
    device = _device(args)
    parallel = from_env(device)  # torchrun: joins the process group (a barrier); else one process
    try:
        parallel.check_same("command line", {k: v for k, v in vars(args).items() if k != "func"})
        with warnings.catch_warnings():  # the trainer's warnings (data, rejected steps): one line each
            warnings.simplefilter("always", RuntimeWarning)
            # numpy's and scipy's overflow notes are internals: our checks report what they lead to
            warnings.filterwarnings("ignore", category=RuntimeWarning, module=r"(numpy|scipy)(\.|$)")
            # the same notes raised by numpy's C loops, attributed to pdeinv's line that called them
            warnings.filterwarnings("ignore", category=RuntimeWarning,
                                    message=r"(overflow|invalid value|divide by zero|underflow) encountered")
            warnings.filterwarnings("ignore", category=FailedRun)  # _run says it, as an error or not
            warnings.showwarning = _one_line
            return _parallel_train(args, out, ckpt, device, parallel)
    except RuntimeError as err:
        if parallel.world_size == 1 or not _lost_peer(err):
            raise
        again = f"continue from {ckpt} with --resume" if ckpt.exists() else "no checkpoint was written"
        if parallel.is_writer:
            why = re.sub(r"^\[[^\]]*\]\s*", "", str(err).strip().splitlines()[0])[:120]  # no C++ source path
            print(f"pdeinv train: a process of the {parallel.world_size}-process run stopped or cannot be "
                  f"reached ({why}); {again}", file=sys.stderr)
        return 1
    finally:
        parallel.close()


def _device(args):
    """``--device`` as a ``torch.device`` of this machine (a usage error naming it otherwise)."""
    from pdeinv.physics.backends.device import resolve

    try:
        return resolve(args.device)
    except ValueError as err:
        raise UsageError(f"--{err}") from None


#: prior draws ``--explain`` takes from the problem's sampler: a sampler that fails, returns the wrong
#: shape or non-finite values is refused before the run, not after its plan said it would work
EXPLAIN_DRAWS = 4


def _explain(args) -> int:
    """``--explain``: the run's plan (:func:`pdeinv.training.plan.plan`) on stdout; nothing trained or
    written. The run's own checks follow it: a run that would be refused (its flags, its memory, a HIG
    step beyond its time limit, a sampler whose first :data:`EXPLAIN_DRAWS` draws fail) is refused here
    too, in the same line, after its plan."""
    from pdeinv.methods.presets import make_rule
    from pdeinv.nets import NONLINEAR_KINDS

    out = None if args.out is None else _check_flags(args)  # the run's --out policy, nothing created
    _check_values(args)
    set_threads(args.threads)
    problem, _, y, x = _problem_and_data(args)
    _refuse_mismatch(args, problem, y, x)  # the run's exit 3, in its words
    print(_plan(args, problem, y, x).explain())
    if y is None and problem.sampler is not None:  # the run's first draws, checked as the run checks them
        import numpy as np

        problem.draws(EXPLAIN_DRAWS, np.random.default_rng(args.seed))
    if out is not None and args.resume:
        from pdeinv.training.checkpoint import Checkpoint, resumable_for

        resumable_for(Checkpoint(out / "checkpoint.pt"), problem, args.method, args.steps,
                      {"seed": args.seed, "n_test": args.n_test, "fresh": args.fresh_draws})
    hidden = _hidden(args.hidden) if args.hidden is not None else None
    rule, hp = make_rule(args.method, problem, problem.noise, linear_net=args.net not in NONLINEAR_KINDS,
                         lr=args.lr, eta=args.eta, tau=args.tau, batch_size=args.batch_size, hidden=hidden,
                         optimizer=args.optimizer)
    _checks.check_rule(rule, args)
    _checks.check_run(problem, args, hp)
    _device(args)
    return 0


def _plan(args, problem, y=None, x=None):
    """The run's :class:`pdeinv.training.plan.Plan` from the command line (own data: ``y``, ``x``)."""
    from pdeinv.training.plan import plan
    from pdeinv.training.trainset import N_TRAIN

    own = None
    if y is not None:
        from pdeinv.posterior import CalibrationStage
        from pdeinv.training.data import own_data

        own = own_data(problem, y, x, args.n_test, 0, False, CalibrationStage(), accept_bad=args.accept_bad)
    hidden = _hidden(args.hidden) if args.hidden is not None else None
    return plan(problem, args.method, net=args.net, hidden=hidden, prior=_prior_stage(args),
                fresh=args.fresh_draws,
                n_train=args.n_train or (len(own.y) if own is not None else N_TRAIN), steps=args.steps,
                batch_size=args.batch_size, own=own, n_test=args.n_test, lr=args.lr, eta=args.eta,
                tau=args.tau, optimizer=args.optimizer)


def _lost_peer(err: RuntimeError) -> bool:
    """Whether ``err`` is a collective failing because another rank died or timed out."""
    import torch.distributed as dist

    text = str(err).lower()
    return isinstance(err, dist.DistError) or any(
        w in text for w in ("connection", "timed out", "timeout", "gloo", "nccl", "peer"))


#: ``--net``: the network kinds a user chooses by name (run.json's ``network.kind``, pdeinv.io.runs.NETWORKS)
NETS = ("default", "linear", "whitened", "reduced", "modal", "unet")


def _network_spec(problem, hp: dict, net: str = "default", data: bool = False) -> dict:
    """run.json's network: the MLP of ``--hidden``, else ``--net`` (the problem's default network, the
    whitened linear map or the prior decoder, :mod:`pdeinv.nets`), with the preset's
    ``rows_per_component`` cap (first-order rules) where the problem has no model_factory."""
    if hp["hidden"] is not None:  # with --net other than default: refused by _check_values
        return {"kind": "mlp", "hidden": list(hp["hidden"])}
    cap = hp.get("rows_per_component")
    own = getattr(problem, "model_factory", None) is not None
    if own and net != "default":
        raise UsageError(f"--net {net}: problem {problem.name!r} builds its own network (model_factory); "
                         "only --net default applies")
    from pdeinv.nets import NONLINEAR_KINDS

    capped = cap and not own and net not in NONLINEAR_KINDS  # the cap is the whitened map's
    spec = {"kind": net, **({"rows_per_component": cap} if capped else {})}
    if data and net == "default" and not own:  # the file's prior, never the scene's (pdeinv.nets.data_base)
        from pdeinv.nets import data_base

        spec["base"] = data_base(problem)
    return spec


def _prior_stage(args):
    """``--prior-fit N``: the prior stage (:class:`pdeinv.training.plan.PriorStage`) with at most N steps;
    0: none; not given: the default stage, its counts derived from the problem."""
    from pdeinv.nets.refine import PriorFit
    from pdeinv.training.plan import PriorStage

    if args.prior_fit is None:
        return PriorStage(PriorFit())
    if args.prior_fit < 0:
        raise UsageError(f"--prior-fit {args.prior_fit}: expected a number of steps >= 0 (0: no prior stage)")
    return PriorStage(PriorFit(steps=args.prior_fit)) if args.prior_fit > 0 else None


def _parallel_train(args, out, ckpt, device, parallel) -> int:
    import torch

    from pdeinv.io.runs import network
    from pdeinv.methods.presets import PRESET, make_rule
    from pdeinv.nets import NONLINEAR_KINDS
    from pdeinv.training.arguments import stop as stopping_rule
    from pdeinv.training.trainer import Trainer
    from pdeinv.training.trainset import N_TRAIN

    from ._folder import FolderCheckpoint, Fresh

    hidden = _hidden(args.hidden) if args.hidden is not None else None
    fresh = Fresh(out, args.overwrite)
    set_threads(args.threads)
    no_cache(args)
    t_build, c_build = time.perf_counter(), time.process_time()
    problem, overrides, y, x = _problem_and_data(args)  # says so when the build is slow
    _refuse_mismatch(args, problem, y, x)  # exit 3 before anything is written
    # metrics.json "setup" (wall seconds) and "setup_cpu" (CPU seconds), with the trainer's phases
    setup = {"build": time.perf_counter() - t_build}
    setup_cpu = {"build": time.process_time() - c_build}
    rule, hp = make_rule(args.method, problem, problem.noise, linear_net=args.net not in NONLINEAR_KINDS,
                         lr=args.lr, eta=args.eta, tau=args.tau, batch_size=args.batch_size, hidden=hidden,
                         optimizer=args.optimizer)
    _checks.check_rule(rule, args)
    _checks.check_run(problem, args, hp)  # memory, HIG step time, --export-samples (before allocating)
    logging.getLogger("pdeinv").debug(f"pdeinv train: --method {args.method} with {hp}")
    torch.manual_seed(args.seed)
    net = _network_spec(problem, hp, args.net, bool(args.data))
    t_net, c_net = time.perf_counter(), time.process_time()
    model = network(problem, net)
    setup["network"], setup_cpu["network"] = time.perf_counter() - t_net, time.process_time() - c_net
    stop = stopping_rule(args.stop, problem, _checks.steps(args, hp), model)
    chosen = _plan(args, problem, y, x) if parallel.is_writer else None  # metrics.json's "plan"
    trainer = Trainer(problem, rule, model, steps=_checks.steps(args, hp),
                      time_budget=args.time_budget,
                      n_train=args.n_train or N_TRAIN, n_test=args.n_test,
                      batch_size=hp["batch_size"] if args.batch_size is not None else PRESET,
                      seed=args.seed, eval_every=args.eval_every, max_failures=args.max_failures,
                      checkpoint=FolderCheckpoint(ckpt, args.checkpoint_every, fresh) if args.checkpoint_every
                      else None,
                      resume=args.resume, stop=stop, data=y, data_x=x, accept_bad=args.accept_bad,
                      device=device, parallel=parallel,
                      prior=_prior_stage(args), fresh=args.fresh_draws,
                      progress=False if getattr(args, "quiet", False) else None,
                      callbacks=[_Heartbeat(_checks.steps(args, hp), chosen,
                                            lines=parallel.is_writer and not sys.stderr.isatty())])
    if not parallel.is_writer:  # trains its shard; rank 0 writes everything
        failed = trainer.fit().metrics["failed"]
        return FAILED if failed and not args.accept_bad else 0
    prepare_out(out)
    try:
        return _run(args, out, problem, overrides, net, hp, trainer, fresh, (setup, setup_cpu), chosen)
    except FileNotFoundError:  # e.g. --resume without a checkpoint: bad input (exit 2)
        raise
    except OSError as err:  # a full disk, no permission: not the input's fault, not numerical
        return _cannot_write(err, out)


def _cannot_write(err: OSError, out: Path) -> int:
    """A write that failed, in one line: the reason, the file, and what resumes it (exit 1)."""
    where = f" ({err.filename})" if err.filename else ""
    fix = "free space" if err.errno in (errno.ENOSPC, errno.EDQUOT) else "fix it"
    again = f"; {fix} and continue with --resume" if (out / "checkpoint.pt").exists() else ""
    print(f"pdeinv train: cannot write: {err.strerror or err}{where}{again}", file=sys.stderr)
    return 1


def _problem_and_data(args):
    """``(problem, overrides, y, x)``: the problem built with the noise level the data declares or
    shows (``args.set`` gets it, so run.json and ``--resume`` see the level trained with) and the data
    file's rows (``None`` without ``--data``)."""
    from pdeinv.problem.units import units_of
    from pdeinv.training.data import (
        no_signal,
        npz_rounding_level,
        read_meta,
        read_noise,
        read_npz,
        undeclared_noise,
    )

    overrides = parse_sets(args.set)
    args.said_noise = overrides.get("noise")  # the user's level (checked against a file's x), before ours
    problem = build_problem("train", args.problem, args.set, steps=args.steps)  # says so when slow
    y, x = read_npz(args.data, problem.operator.n_out, problem.N) if args.data else (None, None)
    if args.data:  # nonlinear physics: data in its own units, before any check runs the physics on them
        units_of(y, problem.operator, f"--data {args.data!r}")
    meta = read_meta(args.data, problem.points) if args.data else {}
    if "noise" in meta and "noise" in overrides and float(overrides["noise"]) != meta["noise"]:
        raise UsageError(f"--set noise={overrides['noise']} conflicts with the noise={meta['noise']:g} the "
                         f"data file {args.data!r} declares; drop one of them")
    if "noise" in meta and "noise" not in overrides and "noise" in problem.settings:  # the file's level
        args.set = [*args.set, f"noise={meta['noise']:g}"]
        overrides = parse_sets(args.set)
        problem = build_problem("train", args.problem, args.set, steps=args.steps)
    rounding = npz_rounding_level(args.data) if args.data else 0.0
    # noisy data with no declared level would be fitted exactly (the noise amplified by the inverse):
    # rounding is noise, and so is what the observations show (pdeinv.training.data.undeclared_noise)
    level = undeclared_noise(args.data, y, problem) if args.data and "noise" not in overrides else rounding
    own_level = args.data and "noise" not in overrides
    why = no_signal(max(level, read_noise(y, problem.operator)), len(y)) if own_level \
        else None  # the check of classical and predict
    if why is not None:
        raise BadData(f"--data {args.data!r} {why} (--set noise=… declares a level instead)")
    if level > problem.noise and "noise" in problem.settings:  # say so, train with it
        why = (f"is stored in lower precision than float64: its rounding is noise of relative level "
               f"{level:.2g}" if level == rounding else f"declares no noise level; its observations show "
               f"noise of relative level {level:.2g} (pdeinv.training.data.undeclared_noise)")
        warnings.warn(f"--data {args.data!r} {why}, above the problem's {problem.noise:g}; training "
                      f"with --set noise={level:.2g} (--set noise=… declares the level)", RuntimeWarning,
                      stacklevel=2)
        args.set = [*args.set, f"noise={level:.2g}"]  # run.json and --resume see the level trained with
        overrides = parse_sets(args.set)
        problem = build_problem("train", args.problem, args.set, steps=args.steps)
    return problem, overrides, y, x


def _refuse_mismatch(args, problem, y, x) -> None:
    """``--data`` whose y are beyond what the run's noise explains (:func:`pdeinv.training.data.beyond_noise`,
    the limit of ``classical`` and ``predict`` too), or far below a noise level the file declares
    (:func:`~pdeinv.training.data.below_noise`): :class:`BadData` (exit 3, one line), unless
    ``--accept-bad``, which trains on it with the trainer's warning."""
    if x is None or args.accept_bad:
        return
    from pdeinv.training.data import against, below_noise, beyond_noise, read_meta

    what, figure = against(problem, y, x)  # one forward pass of the file's rows for both checks
    declared = read_meta(args.data, problem.points).get("noise")
    said = getattr(args, "said_noise", None)
    by = "" if declared or not said else f"--set noise={said}"
    declared = declared or (problem.noise if said else None)
    why = beyond_noise(what, figure, problem.noise, y, x) or (
        below_noise(figure, declared, by) if declared else None)
    if why is not None:
        raise BadData(f"--data {args.data!r}: {why}; --accept-bad trains on it anyway")


def _run(args, out, problem, overrides, net, hp, trainer, fresh, setup=None, chosen=None) -> int:
    """Train under the folder's lock and write every output; see :data:`pdeinv.io.runs.OUTPUTS`."""
    import torch

    from pdeinv.errors import NonFiniteError
    from pdeinv.io.runs import POSTERIOR_FILE, RUN_FILE, clear_outputs, save_run
    from pdeinv.util.files import atomic_write, write_csv
    from pdeinv.util.runlock import RunLock

    from ._plot import training_curves

    ckpt = out / "checkpoint.pt"
    with RunLock(out):  # one run per --out: a second one is refused
        try:
            result = trainer.fit()  # its warnings: one line on stderr each (_train)
        except NonFiniteError:
            fresh()
            if trainer.history:
                write_csv(trainer.history, out / "history.csv")
            raise
        except KeyboardInterrupt as err:  # Ctrl-C, or SIGTERM (pdeinv.cli.signals): 130 / 143
            from pdeinv.cli.signals import exit_code, what

            fresh()
            saved = f"continue from {ckpt} with --resume" if ckpt.exists() else "no checkpoint was written"
            print(f"pdeinv train: {what(err)}; {saved}", file=sys.stderr)
            return exit_code(err)
        fresh()
        metrics = {**result.metrics, **_setup_phases(trainer, setup), "plan": chosen.as_dict(),
                   "method": args.method,
                   "hyperparameters": hp, "settings": {k: v for k, v in problem.settings.items()},
                   "route": result.history[-1].get("route"), "torch_threads": torch.get_num_threads()}
        if args.data:
            metrics["data"] = {"file": str(args.data), **metrics["data"]}
        metrics["accept_bad"] = bool(args.accept_bad)  # beside the verdict "failed" (pdeinv.training.verdict)
        # atomic: a kill while writing never leaves a truncated metrics.json or model.pt
        text = json.dumps(metrics, indent=2, default=str).encode()
        atomic_write(out / "metrics.json", lambda fh: fh.write(text))
        write_csv(result.history, out / "history.csv")
        training_curves(result.history, out / "training.png", f"{problem.name}, {args.method}")
        # the folder was checked before the run (run_folder: new, or --overwrite / --resume of a run)
        save_run(out, args.problem_spec, overrides, net, result.model, result.posterior, overwrite=True)
        written = {"metrics.json", "history.csv", "training.png", "model.pt", RUN_FILE, "checkpoint.pt",
                   *([POSTERIOR_FILE] if result.posterior is not None else [])}
        x_test, y_test = trainer.held_out()
        if args.export_samples is None or args.export_samples:  # ParaView files and a picture of a few
            # held-out samples (EXPORT_SAMPLES unless --export-samples says)
            from pdeinv.io.export import export_run

            files = export_run(out, problem, result.model, x_test, y_test,
                               samples=min(args.export_samples or EXPORT_SAMPLES, len(y_test)),
                               posterior=result.posterior)
            written |= {Path(p).name for p in files.values()}
        clear_outputs(out, keep=written)  # e.g. fields.vtu of an earlier run or a resumed one
        print(f"{problem.name} {'; '.join(_stage_line(st) for st in metrics['stages'])}; "
              f"{metrics['wall_s']:.2f} s -> {args.out}")
        return _verdict(metrics["failed"], args.accept_bad, out)


def _stage_line(stage: dict) -> str:
    """One stage of the summary line: ``sip: 30 steps (steps), x_err 0.159, y_err 9e-13``."""
    name = stage["name"]
    if stage.get("skipped"):
        return f"{name}: skipped ({stage['skipped']})"
    if "conformal_rows" in stage:  # the calibration stage (pdeinv.posterior.stage)
        test = stage.get("test")
        cover = "" if test is None else (f", 90 % intervals cover {test['coverage_90']:.3g} of the test "
                                         f"values (ball {test['ball_coverage_90']:.3g})")
        rows = "rows of the data file" if stage.get("source") == "data" else "draws"
        return f"{name}: {stage['rows']} held-out {rows}{cover}"
    if "kept" in stage and not stage["kept"]:
        return f"{name}: not kept ({stage.get('steps', 0)} steps did not lower the held-out error)"
    # %.3g, never %.4f: "x_err 0.0000" once hid 6e-11
    x_err = "n/a (no x in the data)" if stage.get("x_err") is None else f"{stage['x_err']:.3g}"
    how = f" ({stage['stopped_by']})" if stage.get("stopped_by") else ""
    on = f" on {stage['draws']} draws" if "draws" in stage else ""
    return f"{name}: {stage.get('steps', 0)} steps{how}{on}, x_err {x_err}, y_err {stage['y_err']:.3g}"


def _setup_phases(trainer, setup) -> dict:
    """``{"setup": …, "setup_cpu": …}``: the command's phases (the build, the network) and the trainer's
    (``trainer.setup``, ``trainer.setup_cpu``: timings, not results), in wall and CPU seconds, with
    their ``total`` (build + samples + network fitting)."""
    timed = {}
    trainers = (trainer.setup, trainer.setup_cpu)
    for key, mine, theirs in zip(("setup", "setup_cpu"), setup or ({}, {}), trainers):
        phases = {k: round(v, 3) for k, v in mine.items()}
        phases.update({k: round(v + phases.get(k, 0.0), 3) for k, v in theirs.items()})
        phases["total"] = round(sum(phases.values()), 3)
        timed[key] = phases
    return timed


def _verdict(failed: str | None, accept: bool, out: Path) -> int:
    """Exit code 0, or :data:`FAILED` with one line on stderr when the run failed
    (:mod:`pdeinv.training.verdict`)
    and ``--accept-bad`` was not given; its files are written either way."""
    if not failed:
        return 0
    if accept:
        print(f"pdeinv train: warning: the run failed: {failed}; kept (--accept-bad)", file=sys.stderr)
        return 0
    print(f"pdeinv train: error: the run failed: {failed}; its files are in {out} (metrics.json: "
          "\"failed\"); --accept-bad ends such a run with exit code 0", file=sys.stderr)
    return FAILED


def add_parser(sub) -> None:
    from pdeinv.methods.names import METHOD_NAMES as METHODS
    t = sub.add_parser("train", help="train a network with GD, Adam, SIP or HIG; write metrics.json")
    t.add_argument("problem")
    t.add_argument("--method", choices=sorted(METHODS), default="sip",
                   help="update rule (default: sip, the most accurate; methods/presets.py)")
    t.add_argument("--steps", type=PLAIN_INT, default=None,
                   help="training steps, i.e. updates of the network (default: the method's preset: 30 "
                        "full-batch steps for sip, 1000 (hig: full-batch) otherwise; no limit when "
                        "--time-budget is given); not the physics' time steps, which are --set steps=N")
    t.add_argument("--time-budget", type=PLAIN_FLOAT, default=None, metavar="SECONDS",
                   help="also stop once training wall time exceeds this")
    t.add_argument("--seed", type=PLAIN_INT, default=0,
                   help="seed of everything random: the training and test draws, the batch order, the "
                        "network's initial weights (an integer from 0 to 2^32-1; default 0)")
    t.add_argument("--no-cache", action="store_true", help="no disk cache of factorizations")
    t.add_argument("--explain", action="store_true",
                   help="print what the run will do (backend, inverse, rule, network, stages and their "
                        "counts, memory) and exit without training or writing anything")
    t.add_argument("--out", default=None, metavar="DIR",
                   help="folder for the run's files (created with its parents; one that holds another run "
                        "is refused unless --resume or --overwrite): metrics.json, history.csv, "
                        "training.png, model.pt, run.json, checkpoint.pt, fields.vtu/png")
    add_set_argument(t)
    _rule_arguments(t)
    _network_arguments(t)
    _data_arguments(t)
    _run_arguments(t)
    _checks.add_arguments(t)  # --allow-slow, --max-memory-gb
    declare_ranges(t, RANGES)
    t.set_defaults(func=cmd_train)


#: the range of each numeric flag whose check the trainer or the rule would otherwise make under its own
#: name (``steps=-1``, ``time_budget=-1.0``), checked before any work (:func:`pdeinv.cli.check_numbers`)
RANGES = {"steps": dict(low=1), "lr": dict(above=0), "eta": dict(above=0), "tau": dict(low=0, below=1),
          "batch_size": dict(low=1), "time_budget": dict(above=0), "eval_every": dict(low=1),
          "max_failures": dict(low=1)}


def _rule_arguments(t) -> None:
    """The update rule's settings (their defaults: the presets, methods/presets.py)."""
    t.add_argument("--lr", type=PLAIN_FLOAT, default=None, help="optimizer learning rate (gd, adam, sip)")
    t.add_argument("--eta", type=PLAIN_FLOAT, default=None, help="step scale η (sip, hig)")
    t.add_argument("--tau", type=PLAIN_FLOAT, default=None, help="relative singular-value cut (hig)")
    t.add_argument("--batch-size", type=PLAIN_INT, default=None,
                   help="samples per step (default: the method's preset; sip: every training sample, "
                        "32 with --hidden)")
    t.add_argument("--optimizer", choices=("adam", "sgd"), default=None,
                   help="SIP's proxy optimizer (default: sgd on the curvature-normalized proxy; adam at "
                        "1e-3 with --hidden; methods/presets.py)")
    t.add_argument("--stop", choices=sorted(STOPS), default="auto",
                   help="stopping rule that never looks at x: 'discrepancy' stops once the residual on "
                        "128 held-out observations reaches 1.1x the noise level (the problem's, or an "
                        "estimate when it has none); 'plateau' once that residual has not fallen by 1 %% "
                        "in 3 checks; 'auto' (default): plateau on nonlinear physics, discrepancy on "
                        "noisy problems the denoised target (pdeinv.methods.targets) cannot filter")


def _network_arguments(t) -> None:
    """Which network, and its nonlinear correction's prior fit."""
    t.add_argument("--net", choices=NETS, default="default",
                   help="network (default: the problem's: a linear estimate (the prior decoder where the "
                        "operator is not reversible, else the whitened linear map) trained by the rule, "
                        "plus a nonlinear correction fitted on the prior (--prior-fit); linear: the "
                        "linear estimate alone; modal: the linear map in the operator's modes (heat "
                        "scenes), pdeinv.nets.modal; unet: the SIP paper's U-Net on the observations and the "
                        "physics' linear estimate, trained by the rule end to end, pdeinv.nets.unet; "
                        "pdeinv.nets.default_model)")
    t.add_argument("--prior-fit", type=PLAIN_INT, default=None, metavar="N",
                   help="the prior stage after the rule: fit the default network's nonlinear correction on "
                        "draws of the prior (the scene's sampler, or the rows of --data that carry x) for at "
                        "most N steps, then its data-consistency layer (default: 60 passes over the draws, "
                        "at most 8192 steps; 0: no prior stage, the network stays the rule's estimate)")
    t.add_argument("--hidden", default=None, metavar="W,W", help="MLP hidden widths, e.g. 64,64")


def _data_arguments(t) -> None:
    """Where the training and test rows come from, and how often the test errors are computed."""
    from pdeinv.training.trainset import N_TEST, N_TEST_FILE, N_TRAIN

    t.add_argument("--data", default=None, metavar="FILE.npz",
                   help="train on your own observations: an .npz with y (B, m), optionally x (B, N) "
                        "(used only to report errors). Rows keep their order: the last --n-test rows "
                        "are the test set, the stopping rule's 128 rows (when it is on) come before "
                        "them, the rest train; shuffle the rows first if the file is sorted. The noise "
                        "level is the problem's (--set noise=...)")
    t.add_argument("--n-train", type=PLAIN_INT, default=None,
                   help=f"training samples (default {N_TRAIN}; not with --data)")
    t.add_argument("--fresh-draws", action="store_true",
                   help="train each step on new draws of the scene's prior, x in no loss (the SIP paper's "
                        "protocol; not with --data): the --n-train rows then only fit the input scaling")
    t.add_argument("--n-test", type=PLAIN_INT, default=None,
                   help=f"test samples (default {N_TEST}); with --data the last N rows of the file "
                        f"(default {N_TEST_FILE})")
    t.add_argument("--eval-every", type=PLAIN_INT, default=50, metavar="K",
                   help="compute the held-out test errors (x_err, y_err in history.csv and training.png) "
                        "every K training steps, and after the first and the last (default 50; not counted "
                        "as training time)")


def _run_arguments(t) -> None:
    """Device, threads, outputs, checkpoints, the failure budget and the final check."""
    t.add_argument("--device", default="cpu",
                   help="torch device of the network and of dense/modal/SVD physics: cpu (default), "
                        "cuda, cuda:N (time stepping stays on the CPU). Data parallel: torchrun "
                        "--nproc_per_node=P -m pdeinv train ... (gloo on cpu, NCCL on cuda; the batch "
                        "is the global one and must divide by P; hig on the default networks only)")
    t.add_argument("--threads", type=PLAIN_INT, default=1,
                   help="threads of torch and of numpy/scipy's BLAS/OpenMP pools (default 1: on 2 cores a "
                        "heat_2d step of an MLP took 6.8 ms with one thread and 18-20 ms with two, idle "
                        "machine; pdeinv.util.threads)")
    t.add_argument("--export-samples", type=PLAIN_INT, default=None, metavar="K",
                   help=f"write fields.vtu (ParaView) and fields.png for K test samples (default "
                        f"{EXPORT_SAMPLES}, at most --n-test; 0: none)")
    t.add_argument("--overwrite", action="store_true",
                   help="delete the previous run's files in DIR first (only files pdeinv train writes: "
                        "metrics.json, checkpoint.pt, model.pt, fields.vtu, ...; only in a folder pdeinv "
                        "marked as a run's, never another non-empty folder); not with --resume")
    t.add_argument("--checkpoint-every", type=PLAIN_INT, default=100, metavar="K",
                   help="save DIR/checkpoint.pt atomically every K steps and at the end (0: never)")
    t.add_argument("--resume", action="store_true",
                   help="continue from DIR/checkpoint.pt (same problem, settings, network, seed and "
                        "data); --steps may grow, not shrink below the steps done")
    t.add_argument("--max-failures", type=PLAIN_INT, default=5, metavar="K",
                   help="stop after K consecutive rejected steps (a NaN/Inf loss or update, or a loss "
                        "over 1000x the lowest so far; redoing the rolled-back step does not end a "
                        "streak); each rejection restores the last good state and halves the learning "
                        "rate / eta, never below 1e-12 of it (the run stops there), and it doubles back "
                        "after 50 accepted steps")
    t.add_argument("--accept-bad", action="store_true",
                   help="exit 0 even when the run fails its final check (else exit code 3; the files are "
                        "written either way, the reason in metrics.json's 'failed'): a held-out x_err >= 1, "
                        "no better than predicting zero; without x in the data, predictions with over 2x the "
                        "prior's energy where the physics cannot see (pdeinv.training.verdict)")
