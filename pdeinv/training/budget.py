"""The memory a training run will hold at its peak, by part, and the guard that refuses it before any
part is allocated (the budget and the primitive checks: :mod:`pdeinv.util.memory`)."""

from __future__ import annotations

from ..inverse import TikhonovCG
from ..methods.sip import CHUNK_ENTRIES
from ..nets import network_size
from ..util.memory import GB, HIG_JACOBIAN_GB, check

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
      and ``x``, ``y``, the residual and the local inverse's result (float64); for SIP one chunk of rows
      (:data:`pdeinv.methods.sip.CHUNK_ENTRIES`);
    * ``set-up``: the larger of what building the network needs on top (the prior decoder's draws and Gram
      matrix) and the whitening fit's SVD of the training observations (three ``(n, m)`` arrays): they
      come one after the other and are freed before training;
    * ``inverse``: the generic Tikhonov CG inverse (:class:`pdeinv.inverse.TikhonovCG`, where the operator
      has no spectral basis): its ten ``(B, N)`` work arrays and its bounded reorthogonalization history;
    * ``HIG Jacobian``: HIG's stacked Jacobian on a network that is not linear in its parameters, at most
      its budget (:data:`HIG_JACOBIAN_GB`; HIG refuses or goes matrix-free above it).

    An upper bound (heat_2d at n=256: ~1.5× the peak RSS, benchmarks/notes/scaling.md).
    """
    m, n = problem.operator.n_out, problem.operator.n_in
    size = network_size(problem, "mlp" if hidden else net, hidden)
    d = size["dtype_bytes"]
    copies = STATE_COPIES["sgd" if method == "sip" and optimizer == "sgd" else "adam"]
    rows = min(batch, max(1, CHUNK_ENTRIES // max(m, n, 1))) if method in (None, "sip") else batch
    parts = {
        "data": (n_train + n_test + n_val) * (8 * (m + n) + d * m) + prior_draws * 8 * (m + n),
        "network": copies * d * size["params"] + d * size["buffers"],
        "batch": 2 * d * rows * size["widest"] + 8 * rows * (n + 2 * m),
        "set-up": max(size["build"], 3 * 8 * n_train * m),
    }
    inverse = problem.inverse_simulator
    if method in (None, "sip") and isinstance(inverse, TikhonovCG):
        parts["inverse"] = inverse.memory_bytes(rows)
    linear_net = not hidden and problem.model_factory is None
    if method == "hig" and not linear_net:  # the default networks take the Kronecker route: no J
        parts["HIG Jacobian"] = min(8.0 * batch * m * size["params"], HIG_JACOBIAN_GB * 2**30)
    return parts


def check_training(problem, n_train: int, n_test: int, batch: int, hidden=None, net: str = "default",
                   method: str | None = None, n_val: int = 0, prior_draws: int = 0,
                   optimizer: str = "adam") -> dict:
    """Refuse a training run whose parts (:func:`run_bytes`) would not fit, before any of them is
    allocated, with the estimate, its largest parts and the budget in one line; returns the parts."""
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
