"""One bound on every thread pool a run uses: torch's and the BLAS/OpenMP pools behind numpy and scipy.

``torch.set_num_threads`` bounds torch's intra-op pool only; numpy's and scipy's products run in the
pools of the BLAS they were built with (OpenBLAS, MKL, BLIS) and of OpenMP, which follow
``OMP_NUM_THREADS`` if it was set *before* they loaded and otherwise use every core. On a busy
2-core machine that oversubscription cost ~10× (heat_2d, 150 SIP steps: 27.97 s of training with
``torch.set_num_threads(1)`` alone, 2.61 s with ``OMP_NUM_THREADS=1`` as well). :func:`limit` sets
both at run time, the BLAS/OpenMP side with threadpoolctl (the library scikit-learn and joblib use
for this), so ``pdeinv train --threads 1`` means one thread.
"""

from __future__ import annotations

import torch

#: the active threadpoolctl limiter (kept: it restores the original limits when asked, not when dropped)
_LIMITER = None


def limit(n: int) -> int:
    """Bound torch's intra-op threads and every BLAS/OpenMP pool numpy and scipy use to ``n``."""
    global _LIMITER
    from threadpoolctl import threadpool_limits

    from .._checks import count

    n = count(n, "threads")
    import scipy.linalg  # noqa: F401  - load scipy's BLAS now: a pool loaded later is not limited

    restore()
    torch.set_num_threads(n)
    _LIMITER = threadpool_limits(limits=n)
    return n


def restore() -> None:
    """Undo :func:`limit` on the BLAS/OpenMP pools (``pdeinv.cli.main`` calls it when a command ends,
    so a Python session that runs commands keeps its own settings)."""
    global _LIMITER
    if _LIMITER is not None:
        _LIMITER.restore_original_limits()
        _LIMITER = None


def info() -> list[dict]:
    """The BLAS/OpenMP pools loaded in this process and their thread counts (threadpoolctl's view)."""
    from threadpoolctl import threadpool_info

    return [{k: p.get(k) for k in ("user_api", "internal_api", "num_threads", "filepath")}
            for p in threadpool_info()]
