import numpy as np
import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _one_thread():
    """One thread per test process, torch's and the BLAS/OpenMP pools' (what ``--threads 1`` does,
    pdeinv.util.threads.limit), also for the subprocesses tests start (``OMP_NUM_THREADS``). Two xdist workers
    on a 2-core machine, each with two BLAS threads, oversubscribe it: OpenBLAS's waiting threads spin, and
    a 256-256 MLP step took 0.21 s instead of 0.006 s."""
    import scipy.linalg  # noqa: F401  - scipy's BLAS loaded now: a pool loaded later is not limited
    from threadpoolctl import threadpool_limits

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    with threadpool_limits(limits=1), pytest.MonkeyPatch.context() as mp:
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            mp.setenv(var, "1")
        yield
    torch.set_num_threads(n)


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    """The disk cache (pdeinv.util.cache) in a fresh folder, on: tests never read or write the user's cache.
    Subprocesses started by tests inherit the environment."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("PDEINV_CACHE_DIR", str(tmp_path_factory.mktemp("pdeinv-cache")))
        mp.delenv("PDEINV_NO_CACHE", raising=False)
        yield


@pytest.fixture(autouse=True)
def _seed():
    np.random.seed(0)
    torch.manual_seed(0)
    yield


@pytest.fixture
def one_thread():
    """Small dense work: one torch thread avoids oversubscription on a shared 2-core box."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="session")
def heat():
    """A small heat_1d scene with the modal backend (its inverse is a diagonal filter); files that
    need another one define their own ``heat``."""
    import pdeinv

    return pdeinv.load_problem("heat_1d", n=16, steps=10, backend="modal")


def pytest_collection_modifyitems(items):
    """Tests marked ``slow`` (each over ~20 s on the 2-core machine) run first: pytest-xdist's work stealing
    then spreads the short ones around them, instead of one worker starting a 100-s test at the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # stable: otherwise as collected
