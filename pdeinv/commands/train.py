"""``pdeinv train``: train the default network on a problem and write its results to ``--out``."""

from __future__ import annotations

import json
import sys
import warnings

from . import UsageError, _checks, add_set_argument, build_problem, prepare_out, set_threads

ORDER = 1


def _discrepancy(problem):
    from pdeinv.stopping import DiscrepancyStop

    return DiscrepancyStop(noise=None if problem.noise else "estimate")


#: --stop: name -> problem -> stopping rule (or None). 'auto' stops noisy data by the discrepancy
#: principle and leaves noise-free runs to --steps / --time-budget.
STOPS = {
    "auto": lambda problem: _discrepancy(problem) if problem.noise else None,
    "discrepancy": _discrepancy,
    "none": lambda problem: None,
}


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


def _plot(history: list, path, title: str) -> None:
    """y-loss and test errors against training wall time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = [h["wall_s"] for h in history]
    ev = [h for h in history if "x_err" in h]
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.5), layout="constrained")
    a.semilogy(t, [h["loss"] for h in history], lw=0.8)
    a.set(xlabel="training wall time [s]", ylabel="batch y-loss ½‖P f(y*) − y*‖²", title=title)
    b.semilogy([h["wall_s"] for h in ev], [h["x_err"] for h in ev], "o-", label="x error")
    b.semilogy([h["wall_s"] for h in ev], [h["y_err"] for h in ev], "s-", label="y error")
    b.set(xlabel="training wall time [s]", ylabel="relative L²(Ω) error (test set)")
    b.legend()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def cmd_train(args) -> int:
    """Train the default network; write metrics.json, history.csv, training.png, fields.vtu/png."""
    from pathlib import Path

    import torch

    from pdeinv.checkpoint import Checkpoint
    from pdeinv.errors import NonFiniteError
    from pdeinv.files import atomic_write, write_csv
    from pdeinv.methods.presets import make_rule
    from pdeinv.nets import MLP
    from pdeinv.runlock import RunLock
    from pdeinv.train import Trainer

    out = Path(args.out)
    ckpt = out / "checkpoint.pt"
    if (out / "metrics.json").exists() and not (args.overwrite or args.resume):
        raise UsageError(f"{out / 'metrics.json'} exists; choose another --out, pass --resume to "
                         "continue that run or --overwrite to replace it")
    if ckpt.exists() and not (args.overwrite or args.resume):
        raise UsageError(f"{ckpt} exists (an unfinished or finished run); pass --resume to continue it, "
                         "--overwrite to start over, or choose another --out")
    if args.checkpoint_every < 0:
        raise UsageError(f"--checkpoint-every {args.checkpoint_every} is not allowed; "
                         "expected an integer >= 1, or 0 for no checkpoints")
    if args.resume and args.checkpoint_every == 0:
        raise UsageError("--resume needs checkpoints; drop --checkpoint-every 0")
    hidden = _hidden(args.hidden) if args.hidden else None
    if args.export_samples < 0:
        raise UsageError(f"--export-samples {args.export_samples} is not allowed; expected an integer >= 0")
    set_threads(args.threads)
    problem = build_problem("train", args.problem, args.set)  # says what it builds when slow
    rule, hp = make_rule(args.method, problem.name, problem.noise, lr=args.lr, eta=args.eta, tau=args.tau,
                         batch_size=args.batch_size, hidden=hidden, optimizer=args.optimizer)
    _checks.check_run(problem, args, hp)  # memory, HIG step time, --export-samples (before allocating)
    stop = STOPS[args.stop](problem)
    torch.manual_seed(args.seed)
    if hp["hidden"] is not None:
        model = MLP(problem.operator.n_out, problem.operator.n_in, hidden=tuple(hp["hidden"]))
    else:
        model = problem.model()
    trainer = Trainer(problem, rule, model, steps=_checks.steps(args), time_budget=args.time_budget,
                      n_train=args.n_train, n_test=args.n_test, batch_size=hp["batch_size"],
                      seed=args.seed, eval_every=args.eval_every, max_failures=args.max_failures,
                      checkpoint=Checkpoint(ckpt, args.checkpoint_every) if args.checkpoint_every else None,
                      resume=args.resume, stop=stop)
    prepare_out(out)
    with RunLock(out):  # one run per --out: a second one is refused
        try:
            with warnings.catch_warnings():  # a rejected step: one line on stderr, not a warning's two
                warnings.simplefilter("always", RuntimeWarning)
                warnings.showwarning = _one_line
                result = trainer.fit()
        except NonFiniteError:
            if trainer.history:
                write_csv(trainer.history, out / "history.csv")
            raise
        except KeyboardInterrupt:
            saved = f"continue from {ckpt} with --resume" if ckpt.exists() else "no checkpoint was written"
            print(f"pdeinv train: interrupted; {saved}", file=sys.stderr)
            return 130
        metrics = {**result.metrics, "method": args.method, "hyperparameters": hp,
                   "settings": {k: v for k, v in problem.settings.items()},
                   "route": result.history[-1].get("route"), "torch_threads": torch.get_num_threads()}
        # atomic: a kill while writing never leaves a truncated metrics.json or model.pt
        text = json.dumps(metrics, indent=2, default=str).encode()
        atomic_write(out / "metrics.json", lambda fh: fh.write(text))
        write_csv(result.history, out / "history.csv")
        _plot(result.history, out / "training.png", f"{problem.name}, {args.method}")
        atomic_write(out / "model.pt", lambda fh: torch.save(result.model.state_dict(), fh))
        if args.export_samples:  # ParaView files and a picture of a few held-out samples
            from pdeinv.export import export_run
            from pdeinv.train import TEST_DATA, seed_stream

            test = problem.sample(args.n_test, seed_stream(args.seed, TEST_DATA))
            export_run(out, problem, result.model, *test, samples=min(args.export_samples, args.n_test))
        print(f"{problem.name} {args.method}: {metrics['steps']} steps ({metrics['stopped_by']}) in "
              f"{metrics['wall_s']:.2f} s, "
              f"x_err {metrics['x_err']:.4f}, y_err {metrics['y_err']:.4f} -> {out}")
        return 0


def add_parser(sub) -> None:
    from pdeinv.methods.names import METHOD_NAMES as METHODS

    t = sub.add_parser("train", help="train a network with GD, Adam, SIP or HIG; write metrics.json")
    t.add_argument("problem")
    t.add_argument("--method", choices=sorted(METHODS), default="adam")
    t.add_argument("--steps", type=int, default=None,
                   help="training steps (default 1000, or no limit when --time-budget is given)")
    t.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="also stop once training wall time exceeds this")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--out", required=True, metavar="DIR")
    add_set_argument(t)
    t.add_argument("--lr", type=float, default=None, help="optimizer learning rate (gd, adam, sip)")
    t.add_argument("--eta", type=float, default=None, help="step scale η (sip, hig)")
    t.add_argument("--tau", type=float, default=None, help="relative singular-value cut (hig)")
    t.add_argument("--batch-size", type=int, default=None)
    t.add_argument("--optimizer", choices=("adam", "sgd"), default=None,
                   help="SIP's proxy optimizer (default: adam, sgd for noisy data; see methods/presets.py)")
    t.add_argument("--stop", choices=sorted(STOPS), default="auto",
                   help="stopping rule that never looks at x: 'discrepancy' stops once the residual on "
                        "128 held-out observations reaches 1.1x the noise level (the problem's, or an "
                        "estimate when it has none); 'auto' (default) uses it on noisy problems only")
    t.add_argument("--hidden", default=None, metavar="W,W", help="MLP hidden widths, e.g. 64,64")
    t.add_argument("--n-train", type=int, default=1024)
    t.add_argument("--n-test", type=int, default=128)
    t.add_argument("--eval-every", type=int, default=50)
    t.add_argument("--threads", type=int, default=1,
                   help="torch threads (default 1: on 2 cores a heat_2d step of the default MLP took "
                        "6.8 ms with one thread and 18-20 ms with two, idle machine; "
                        "set OMP_NUM_THREADS to limit numpy's BLAS as well)")
    t.add_argument("--export-samples", type=int, default=3, metavar="K",
                   help="write fields.vtu (ParaView) and fields.png for K test samples (0: none)")
    t.add_argument("--overwrite", action="store_true",
                   help="replace an existing DIR/metrics.json and DIR/checkpoint.pt")
    t.add_argument("--checkpoint-every", type=int, default=100, metavar="K",
                   help="save DIR/checkpoint.pt atomically every K steps and at the end (0: never)")
    t.add_argument("--resume", action="store_true",
                   help="continue from DIR/checkpoint.pt (same problem, settings, network and seed)")
    t.add_argument("--max-failures", type=int, default=5, metavar="K",
                   help="stop after K consecutive steps with a NaN/Inf loss or update "
                        "(each rejected step halves the learning rate / eta)")
    _checks.add_arguments(t)  # --allow-slow, --max-memory-gb
    t.set_defaults(func=cmd_train)
