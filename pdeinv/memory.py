"""Memory estimates, checked against a budget *before* anything big is allocated.

A run that does not fit should be refused in a second with a number, not killed after
minutes without one (``heat_2d --set n=20000`` grew to 23.7 GB and got SIGKILL). Each
check estimates the bytes a step will need and raises :class:`MemoryBudgetError` (a
``ValueError``: exit code 2 on the command line) naming the estimate, the budget and
what to change when the estimate exceeds the budget.

**Budget:** ``set_budget(gb)`` (the CLI's ``--max-memory-gb``) or the environment variable
``PDEINV_MAX_MEMORY_GB``; otherwise 90 % of the memory available now (``MemAvailable`` in
``/proc/meminfo``, else ``os.sysconf``; :data:`AVAILABLE_SHARE`): the estimates are upper bounds, so
the machine's free memory itself is the limit (it was half of it, which refused runs that fit).
Without any of these (other systems) nothing is refused.

**Estimates** are rough upper bounds, good to a small factor, not exact accounting:

* mesh and physics: :data:`BYTES_PER_NODE` per mesh node by dimension — the mesh arrays,
  the assembled P1 mass and stiffness matrices with their assembly temporaries, one sparse
  factorization and the modal basis. Measured on ``heat_2d`` (P1, modal backend):
  n = 128 (16 129 unknowns) raised the peak RSS by 300 MB, ~19 kB per node; 1-D and 3-D
  are scaled by the factorization fill. P2 has ~4× the nodes of P1 on the same mesh.
  The factorization part, measured by ``benchmarks/crossover.py`` (SuperLU's exact
  ``nnz(L + U)``; cholespy needs about half): 2-D 0.8–1.9 kB per node up to 10⁶ nodes,
  3-D 6 kB at 12 167 nodes, 10 kB at 29 791, 14 kB at 59 319 (fill grows like N^{1/3} per
  node), so the per-node constants stay upper bounds up to ~10⁵ 3-D nodes; above
  :data:`pdeinv.solvers.AMG_CROSSOVER` the heat operators use AMG-CG, whose hierarchy is
  ~0.3 kB per node (2-D and 3-D).
* sensors: the observation vector of one sample (records × sensors) and the sensor matrix.
* training (:func:`run_bytes`): the data sets and the prior fit's draws, the network that ``--net`` /
  ``--hidden`` actually builds (value, gradient and two Adam moments per parameter in its dtype, its
  buffers, and what building it needs on top), one batch through network and physics, the
  generic Tikhonov CG inverse's ``(B, N)`` arrays and bounded history, and HIG's stacked Jacobian.
"""

from __future__ import annotations

import math
import os

GB = 1e9
#: HIG's default budget for a dense stacked Jacobian, in GiB (``HIG.max_jacobian_gb``; above it HIG refuses
#: the route itself, so ``pdeinv train``'s step-time check leaves it to HIG)
HIG_JACOBIAN_GB = 4.0

#: bytes per mesh node (P1) for the mesh, matrices, factorization and modal basis, by dimension
BYTES_PER_NODE = {1: 2_000, 2: 20_000, 3: 60_000}

#: the default budget's share of the memory available now (``MemAvailable``): the machine's free memory
#: (issue 35), less a margin for what the estimates do not count (Python, torch, the OS's caches)
AVAILABLE_SHARE = 0.9

_budget_gb: float | None = None


class MemoryBudgetError(ValueError):
    """An estimate above the memory budget: bad input for this machine (exit code 2)."""


def set_budget(gb: float | None) -> None:
    """Use ``gb`` gigabytes (10⁹ bytes) as the budget; ``None`` restores the default."""
    global _budget_gb
    if gb is not None and (isinstance(gb, bool) or not isinstance(gb, (int, float))
                           or not math.isfinite(gb) or gb <= 0):
        raise ValueError(f"--max-memory-gb {gb!r} is not allowed; expected a finite number of GB > 0")
    _budget_gb = None if gb is None else float(gb)


def available_bytes() -> int | None:
    """Memory available to new allocations now (``MemAvailable``), or ``None`` if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def budget() -> tuple[float, str]:
    """``(bytes, where it comes from)``; ``math.inf`` when nothing says."""
    if _budget_gb is not None:
        return _budget_gb * GB, "--max-memory-gb"
    env = os.environ.get("PDEINV_MAX_MEMORY_GB")
    if env:
        try:
            value = float(env)
        except ValueError:
            raise ValueError(f"PDEINV_MAX_MEMORY_GB={env!r} is not a number of GB") from None
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"PDEINV_MAX_MEMORY_GB={env!r} is not allowed; expected a number of GB > 0")
        return value * GB, "PDEINV_MAX_MEMORY_GB"
    avail = available_bytes()
    if avail is None:
        return math.inf, "unknown available memory"
    return AVAILABLE_SHARE * avail, (f"{AVAILABLE_SHARE:.0%} of the {avail / GB:.3g} GB available; "
                                     "set it with --max-memory-gb")


def check(nbytes: float, what: str, fix: str) -> None:
    """Refuse (:class:`MemoryBudgetError`) when ``nbytes`` exceeds the budget."""
    limit, source = budget()
    if nbytes > limit:
        raise MemoryBudgetError(f"{what} needs about {nbytes / GB:.3g} GB of memory, above the budget of "
                                f"{limit / GB:.3g} GB ({source}); {fix}")


def check_mesh(nodes: float, dim: int, what: str, fix: str) -> None:
    """Refuse a mesh of ``nodes`` nodes in ``dim`` dimensions that would not fit."""
    check(nodes * BYTES_PER_NODE.get(dim, BYTES_PER_NODE[3]), f"{what} ({nodes:.3g} nodes)", fix)


def network_parameters(n_in: int, n_out: int, hidden) -> int:
    """Parameters of a dense network ``n_in -> hidden... -> n_out`` (weights and biases)."""
    widths = [n_in, *hidden, n_out]
    return sum(a * b + b for a, b in zip(widths, widths[1:]))


def training_bytes(n_obs: int, n_unknowns: int, n_train: int, n_test: int, n_params: int,
                   batch: int, widest: int) -> float:
    """Data sets (x, y float64 and y float32), network state (16 B per parameter), one batch's
    activations (``widest`` values per sample, ×4 for the backward pass)."""
    data = (n_train + n_test) * (8 * (n_obs + n_unknowns) + 4 * n_obs)
    return data + 16 * n_params + 16 * batch * widest


#: copies per trained parameter in its dtype: value, gradient and, with Adam, two moments
STATE_COPIES = {"adam": 4, "sgd": 2}


def run_bytes(problem, n_train: int, n_test: int, batch: int, hidden=None, net: str = "default",
              method: str | None = None, n_val: int = 0, prior_draws: int = 0,
              optimizer: str = "adam") -> dict:
    """What a training run will hold at its peak, by part (bytes; each an upper bound to a small factor):

    * ``data``: training, test and stopping rows (``x``, ``y`` in float64, ``y`` again in the network's
      dtype) and the prior fit's draws (``x``, ``y``), all alive at the prior fit;
    * ``network``: the network ``--net`` / ``--hidden`` builds (:func:`pdeinv.nets.network_size`; the
      default's decoder-or-fallback counted as the larger): its buffers, and per trained parameter its
      value, gradient and, with Adam (``optimizer``; GD and Adam rules: Adam), two moments;
    * ``batch``: one batch through network and physics: the output and its gradient at the widest layer,
      and ``x``, ``y``, the residual and the local inverse's result (float64);
    * ``set-up``: the larger of what building the network needs on top (the prior decoder's draws and Gram
      matrix) and the whitening fit's SVD of the training observations (three ``(n, m)`` arrays): they
      come one after the other and are freed before training;
    * ``inverse``: the generic Tikhonov CG inverse (:class:`pdeinv.inverse.TikhonovCG`, where the operator
      has no spectral basis): its ten ``(B, N)`` work arrays and its bounded reorthogonalization history;
    * ``HIG Jacobian``: HIG's stacked Jacobian on a network that is not linear in its parameters, at most
      its budget (:data:`HIG_JACOBIAN_GB`; HIG refuses or goes matrix-free above it).

    Measured against the peak RSS of ``pdeinv train heat_2d --set n=256`` (one SIP step, the reduced
    default network): 7.2 GB, this estimate 11 GB (docs/scaling.md).
    """
    from .inverse import TikhonovCG
    from .nets import network_size

    m, n = problem.operator.n_out, problem.operator.n_in
    size = network_size(problem, "mlp" if hidden else net, hidden)
    d = size["dtype_bytes"]
    copies = STATE_COPIES["sgd" if method == "sip" and optimizer == "sgd" else "adam"]
    parts = {
        "data": (n_train + n_test + n_val) * (8 * (m + n) + d * m) + prior_draws * 8 * (m + n),
        "network": copies * d * size["params"] + d * size["buffers"],
        "batch": 2 * d * batch * size["widest"] + 8 * batch * (n + 2 * m),
        "set-up": max(size["build"], 3 * 8 * n_train * m),
    }
    inverse = getattr(problem, "inverse_simulator", None)
    if method in (None, "sip") and isinstance(inverse, TikhonovCG):
        parts["inverse"] = inverse.memory_bytes(batch)
    linear_net = not hidden and getattr(problem, "model_factory", None) is None
    if method == "hig" and not linear_net:  # the default networks take the Kronecker route: no J
        parts["HIG Jacobian"] = min(8.0 * batch * m * size["params"], HIG_JACOBIAN_GB * 2**30)
    return parts


def check_training(problem, n_train: int, n_test: int, batch: int, hidden=None, net: str = "default",
                   method: str | None = None, n_val: int = 0, prior_draws: int = 0,
                   optimizer: str = "adam") -> dict:
    """Refuse a training run whose parts (:func:`run_bytes`) would not fit, before any of them is
    allocated, with the estimate, its largest parts and the budget in one line; returns the parts."""
    from .nets import network_size

    parts = run_bytes(problem, n_train, n_test, batch, hidden, net, method, n_val, prior_draws, optimizer)
    m, n = problem.operator.n_out, problem.operator.n_in
    top = sorted(parts.items(), key=lambda kv: -kv[1])[:3]
    what = ", ".join(f"{k} {v / GB:.3g}" for k, v in top)
    params = network_size(problem, "mlp" if hidden else net, hidden)["params"]
    size_net = f"--hidden {','.join(map(str, hidden))}" if hidden else f"--net {net}"
    check(sum(parts.values()), f"training {problem.name} ({n_train} + {n_test} samples of {m} observations "
                               f"and {n} unknowns, {size_net}: a network of {params:.3g} parameters; "
                               f"GB: {what})",
          "use a smaller --n-train / --n-test or --batch-size, another --net or --hidden, or a coarser mesh")
    return parts
