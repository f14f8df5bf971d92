"""Checks ``pdeinv train`` runs after building the problem and before building the network:
memory, HIG's step time, the number of exported samples. Each raises :class:`UsageError`
(exit 2, one line) or prints one warning line; none allocates anything large."""

from __future__ import annotations

import sys

from . import UsageError

#: HIG step-time model: the dense stacked Jacobian (``batch · n_out`` rows × ``n_params``
#: columns) and its SVD cost about ``rows · cols · min(rows, cols)`` flops at this rate.
#: Calibrated with one torch thread on the 2-core machine of the README (see
#: :data:`HIG_CALIBRATION`); an estimate to a factor of ~3, enough to tell 1 s from 1 min.
HIG_FLOPS_PER_S = 1.5e10
#: refuse HIG runs whose estimated step exceeds this many seconds, unless --allow-slow
HIG_MAX_STEP_S = 10.0
#: what the rate rests on (one torch thread, 2-core machine shared with other jobs, so noisy)
HIG_CALIBRATION = """issue 17: the defaults (MLP (32, 32), batch 8) took 20-50 s per step on heat_2d
and the sensor scenes; this model gives 19 s for heat_2d (7688 x 63 553) and ~400 s for
wave_sensors_2d (24 576 x 134 k), 0.007 s for heat_1d. Measured here under load: heat_2d
(16,) batch 1 (961 x 31 729) 6.4 s (2.1 s idle, README), (32, 32) batch 8 1.8 s after the HIG
routes got faster, (16,) batch 4 (3844 x 31 729) 187 s: the routes differ by shape, the model
is an order of magnitude, to be recalibrated when methods/hig*.py change.
Recalibrated after HIG works on the r compressed rows per sample (heat_2d: 217 of 961): the
default heat_2d run (1736 x 63 553 rows x params, 1.9e11 by this model) took 22 s per step
under load (8.7e9 flop/s); (16,) batch 1 idle 2.1 s for 2.9e10 (1.4e10 flop/s): 1.5e10."""


#: HIG's matrix-free route (taken when the dense Jacobian exceeds its budget): ``probes · (2 + 2 ·
#: power_iters)`` Jacobian products, each ``batch · (2 · n_params + 2 · r · N)`` flops (network and
#: rank-r physics), at this rate. Calibrated: heat_2d, MLP (64, 64), the full batch (1024 × 217 rows ×
#: 128 193 parameters, 5.2e11 flops by this model) took 97 s per step under load, not refused before.
HIG_MATRIX_FREE_FLOPS_PER_S = 5e9


def hig_matrix_free_seconds(per_sample: int, n_in: int, n_params: int, batch: int, probes: int,
                            power_iters: int) -> float:
    passes = probes * (2 + 2 * power_iters)
    return passes * batch * (2 * n_params + 2 * per_sample * n_in) / HIG_MATRIX_FREE_FLOPS_PER_S


#: the SVD route (more rows than parameters: HIG's ``auto`` takes it, not the Gram) costs about this
#: many times the Gram's ``rows · cols²``: heat_1d, MLP (16,), the full batch (18 432 × 2 095) took
#: 64 s per step under load, and 17 s with 256 rows (4 608 × 2 095), not refused before
HIG_SVD_FACTOR = 14.0


def hig_step_seconds(n_out: int, n_params: int, batch: int) -> float:
    rows = batch * n_out
    svd = HIG_SVD_FACTOR if rows > n_params else 1.0
    return svd * rows * n_params * min(rows, n_params) / HIG_FLOPS_PER_S


def n_parameters(problem, hidden, net: str = "default") -> int:
    from pdeinv.nets import network_size
    from pdeinv.util.memory import network_parameters

    m, n = problem.operator.n_out, problem.operator.n_in
    if net == "unet":
        return network_size(problem, net)["params"]
    return network_parameters(m, n, hidden) if hidden else m * m + m * n + n


def check_rule(rule, args) -> None:
    """Refuse a rule that fits true fields (its declaration ``needs_fields``) with ``--fresh-draws``."""
    if rule.needs_fields and getattr(args, "fresh_draws", False):
        raise UsageError(f"--method {args.method} fits the true fields x of its training rows, and "
                         "--fresh-draws trains on new observations whose x no loss sees: drop one of them, "
                         "or use a physics-based rule (sip, adam, gd, hig)")


def check_run(problem, args, hp: dict) -> None:
    """Refuse a run that would not fit in memory (:func:`pdeinv.training.plan.check_training`) or a HIG
    run whose step would take longer than :data:`HIG_MAX_STEP_S` (unless ``--allow-slow``);
    warn when ``--export-samples`` is above ``--n-test``."""
    from pdeinv.training.plan import check_training
    from pdeinv.training.trainset import N_TRAIN

    n_train = args.n_train or N_TRAIN
    _prior_fit_applies(problem, args)
    # the trainer checks it under the API's names (a data file's rows: there, with the flags too)
    given = getattr(args, "batch_size", None) is not None  # a preset's rows per step are capped there
    fresh = getattr(args, "fresh_draws", False)  # each step's rows are new draws: n_train fits the scaling
    if given and not getattr(args, "data", None) and not fresh and (hp["batch_size"] or 0) > n_train:
        default = "" if args.n_train else " (its default)"
        raise UsageError(f"--batch-size {hp['batch_size']} is larger than --n-train {n_train}{default}; "
                         f"expected --batch-size <= {n_train}")
    batch = (hp["batch_size"] or n_train) if fresh else min(hp["batch_size"] or n_train, n_train)
    check_training(problem, n_train, args.n_test, batch, hp["hidden"],
                          net=getattr(args, "net", "default"), method=args.method, n_val=128,
                          prior_draws=_prior_draws(problem, args), optimizer=hp.get("optimizer") or "adam",
                          rows_per_component=hp.get("rows_per_component"))
    # the default networks (no --hidden, no network of the problem's own) are linear in θ: HIG takes
    # its Kronecker route there, which never forms J (pdeinv.methods.hig.kron): nothing to estimate
    from pdeinv.nets import NONLINEAR_KINDS

    net = getattr(args, "net", "default")
    default_net = not hp["hidden"] and problem.model_factory is None and net not in NONLINEAR_KINDS
    if args.method == "hig" and not default_net and not getattr(args, "allow_slow", False):
        from pdeinv.physics.capabilities import modal_basis

        basis = modal_basis(problem.operator)  # HIG works on rank-r rows (pdeinv.methods.hig.compress)
        m = problem.operator.n_out
        per_sample = min(m, len(basis.g)) if basis is not None else m
        batch = hp["batch_size"] or n_train
        rows, cols = batch * per_sample, n_parameters(problem, hp["hidden"], net)
        from pdeinv.methods.hig.randomized import memory_bytes
        from pdeinv.methods.hig.routes import SVD
        from pdeinv.methods.hig.rule import HIG
        from pdeinv.util.memory import HIG_JACOBIAN_GB

        budget = HIG_JACOBIAN_GB * 2**30
        if SVD.bytes_per_entry * rows * cols <= budget:  # the dense routes (as HIG budgets them)
            est, route = hig_step_seconds(per_sample, cols, batch), f"Jacobian {rows} x {cols}"
        elif hp["hidden"]:  # the MLP takes its last layer's exact step (pdeinv.methods.hig.layers): ms
            est, route = 0.0, "the last layer's exact step"
        elif memory_bytes(cols, HIG.probes, rows) <= budget:  # HIG goes matrix-free (hig_randomized)
            est = hig_matrix_free_seconds(per_sample, problem.operator.n_in, cols, batch, HIG.probes,
                                          HIG.power_iters)
            route = f"matrix-free: {HIG.probes} probes through a Jacobian {rows} x {cols}"
        else:  # no route fits: HIG refuses it itself, naming the GB
            est, route = 0.0, ""
        if est > HIG_MAX_STEP_S:
            raise UsageError(
                f"HIG on {problem.name} would take about {est:.3g} s per step ({route}, "
                f"--hidden {','.join(map(str, hp['hidden'] or ()))} --batch-size {batch}); "
                f"limit {HIG_MAX_STEP_S:g} s: use e.g. --hidden 16 --batch-size 1, the default network "
                "(no --hidden: HIG's exact Kronecker route), or pass --allow-slow")
    if args.export_samples is not None and args.export_samples > args.n_test:  # the default: quietly fewer
        print(f"pdeinv train: warning: --export-samples {args.export_samples} is more than the "
              f"{args.n_test} test samples (--n-test); exporting {args.n_test}", file=sys.stderr)


def _prior_fit_applies(problem, args) -> None:
    """``--prior-fit N`` (N > 0) on a network with no part the prior stage fits: refused (was ignored)."""
    from pdeinv.training.plan import prior_part

    net = getattr(args, "net", "default")
    if (getattr(args, "prior_fit", None) or 0) > 0 and not prior_part(problem, net, args.hidden):
        what = f"--hidden {args.hidden}" if args.hidden else f"--net {net}"
        raise UsageError(f"--prior-fit {args.prior_fit} does not apply: {what} of {problem.name} has no part "
                         "fitted on prior draws (the default network and --net unet have one); drop it")


def _prior_draws(problem, args) -> int:
    """The prior draws the trainer will hold for the default network's prior stage (0 without one):
    :func:`pdeinv.training.plan.draw_count`."""
    from pdeinv.training.plan import draw_count, prior_part

    if args.prior_fit == 0 or not prior_part(problem, getattr(args, "net", "default"), args.hidden):
        return 0
    return draw_count(problem.N, problem.operator.forward_flops())


def steps(args, hp: dict | None = None) -> int | None:
    """``--steps`` as given; when it is not: the method's preset (``hp["steps"]``, else 1000), or no
    step limit if ``--time-budget`` is given."""
    from pdeinv.methods.presets import preset_steps

    return args.steps if args.steps is not None else preset_steps(hp, args.time_budget)


def add_arguments(parser) -> None:
    """The flags :func:`check_run` reads besides train's own: --allow-slow, --max-memory-gb."""
    from . import add_memory_argument

    parser.add_argument("--allow-slow", action="store_true",
                        help=f"run HIG even when its estimated step exceeds {HIG_MAX_STEP_S:g} s")
    add_memory_argument(parser)
