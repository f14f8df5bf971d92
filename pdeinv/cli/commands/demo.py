"""``pdeinv demo``: forward and adjoint on a sample batch, with timings."""

from __future__ import annotations

import time

from . import PLAIN_INT, UsageError, add_memory_argument, add_set_argument, build_problem

ORDER = 0


def cmd_demo(args) -> int:
    """Build a problem, run forward and adjoint on a batch, print what happened.

    The adjoint of linear physics is ``Pᵀ r``; of nonlinear physics (Allen–Cahn, sine-Gordon), the
    adjoint of its linearization at the batch, ``P'(x)ᵀ r`` (``vjp``). ``dot_product_test`` is
    ``|⟨A v, r⟩ − ⟨v, Aᵀ r⟩| / (‖A v‖ ‖r‖)`` for that ``A`` (``P``, or ``P'(x)`` with ``v`` random):
    rounding-level when the adjoint is exact. ``y_over_x_L2`` compares L²(Ω) norms when the problem
    observes fields on the mesh and Euclidean norms otherwise (sensor time series: the observation is
    not a field)."""
    import numpy as np

    from pdeinv.physics.capabilities import observes_field
    from pdeinv.physics.nonlinear import is_linear
    from pdeinv.util import memory

    if args.batch < 1:
        raise UsageError(f"--batch {args.batch} is not allowed; expected an integer >= 1")
    t0 = time.perf_counter()
    problem = build_problem("demo", args.problem, args.set)
    t_build = time.perf_counter() - t0
    op = problem.operator
    memory.check(8 * 4 * args.batch * (op.n_in + op.n_out), f"demo batch of {args.batch} samples",
                 "use a smaller --batch")
    x, y = problem.sample(args.batch, seed=0)
    t0 = time.perf_counter()
    y = op.forward(x)
    t_fwd = time.perf_counter() - t0
    rng = np.random.default_rng(1)
    r = rng.standard_normal(y.shape)
    linear = is_linear(op)
    v, av = (x, y) if linear else (rng.standard_normal(x.shape), None)
    if av is None:
        av = op.jvp(x, v)
    t0 = time.perf_counter()
    a = op.adjoint(r) if linear else op.vjp(x, r)
    t_adj = time.perf_counter() - t0
    # |<P v, r> − <v, Pᵀ r>| over the sides' scales; where both vanish (a field damped or carried out of
    # the domain to zero) the identity holds exactly: 0
    top = float(np.max(np.abs(av))) or 1.0  # P v at 1e-169 (advected out): its squares would underflow
    av_, a_ = av / top, a / top
    scale = np.linalg.norm(av_) * np.linalg.norm(r) + np.linalg.norm(v) * np.linalg.norm(a_)
    dot = float(abs(np.vdot(av_, r) - np.vdot(v, a_)) / scale) if scale > 0 else 0.0
    report = {
        "problem": problem.name,
        "unknowns": problem.N,
        "operator": repr(op),
        "physics": "linear (adjoint: P^T r)" if linear else
                   "nonlinear (adjoint: P'(x)^T r, of the linearization at the batch)",
        "backend_choice": getattr(op, "choice", None),
        "batch": args.batch,
        "build_s": t_build,
        "forward_s": t_fwd,
        "adjoint_s": t_adj,
        "dot_product_test": dot,
        "y_over_x": float(np.mean((problem.disc.norm(y) if observes_field(op) else np.linalg.norm(y, axis=1))
                                  / problem.disc.norm(x))),
    }
    for k, v in report.items():
        print(f"{k:>18}: {v:.3g}" if isinstance(v, float) else f"{k:>18}: {v}")
    return 0


def add_parser(sub) -> None:
    d = sub.add_parser("demo", help="forward + adjoint on a sample batch, with timings")
    d.add_argument("problem", nargs="?", default="heat_2d")
    d.add_argument("--batch", type=PLAIN_INT, default=64, help="samples in the timed batch (default 64)")
    add_set_argument(d)
    add_memory_argument(d)
    d.set_defaults(func=cmd_demo)
