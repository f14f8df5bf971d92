"""Memory estimates, checked against a budget *before* anything big is allocated.

A run that does not fit should be refused in a second with a number, not killed after
minutes without one (``heat_2d --set n=20000`` grew to 23.7 GB and got SIGKILL). Each
check estimates the bytes a step will need and raises :class:`MemoryBudgetError` (a
``ValueError``: exit code 2 on the command line) naming the estimate, the budget and
what to change when the estimate exceeds the budget.

**Budget:** ``set_budget(gb)`` (the CLI's ``--max-memory-gb``) or the environment variable
``PDEINV_MAX_MEMORY_GB``; otherwise 90 % of the memory available now (``MemAvailable`` in
``/proc/meminfo``, else ``os.sysconf``; :data:`AVAILABLE_SHARE`): the estimates are upper bounds, so
the machine's free memory itself is the limit.
Without any of these (other systems) nothing is refused.

**Estimates** are rough upper bounds, good to a small factor, not exact accounting:

* mesh and physics: :data:`BYTES_PER_NODE` per mesh node by dimension — the mesh arrays,
  the assembled P1 mass and stiffness matrices with their assembly temporaries, one sparse
  factorization and the modal basis (heat_2d: ~19 kB per node of peak RSS); 1-D and 3-D are
  scaled by the factorization fill. P2 has ~4× the nodes of P1 on the same mesh. A 3-D factor's fill
  per node grows like ``N^{1/3}``, so the per-node constants stay upper bounds up to ~10⁵ 3-D nodes;
  above :data:`pdeinv.fem.solvers.AMG_CROSSOVER` the heat operators use AMG-CG, whose hierarchy is far
  smaller (``benchmarks/crossover.py``).
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

#: bytes per mesh node (P1) for the mesh, matrices, factorization and modal basis, by dimension; 1-D:
#: the modal basis' block Krylov start peaks at ~5.9 kB a node (heat_1d n=10⁶, uncached: 6.08 GB RSS)
BYTES_PER_NODE = {1: 8_000, 2: 20_000, 3: 60_000}

#: the default budget's share of the memory available now (``MemAvailable``): the machine's free memory,
#: less a margin for what the estimates do not count (Python, torch, the OS's caches)
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
