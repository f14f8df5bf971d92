"""pdeinv.util.clock.Budget: the thread's CPU seconds, with the wall clock capped."""

import time

from pdeinv.util.clock import Budget


def _spin(seconds):
    t0 = time.thread_time()
    while time.thread_time() - t0 < seconds:
        pass


def test_sleeping_spends_no_budget_but_the_wall_cap_ends_it():
    b = Budget(0.2, wall_factor=3.0)
    time.sleep(0.3)  # waiting (another process on the core, a GPU) costs no CPU seconds
    assert b.spent() < 0.05 and not b.over()
    time.sleep(0.35)  # past 3 × 0.2 wall seconds
    assert b.over()


def test_computing_spends_the_budget_and_ahead_looks_one_chunk_further():
    b = Budget(0.3)
    _spin(0.2)
    assert 0.2 <= b.spent() and not b.over() and b.over(ahead=2.0)
    _spin(0.15)
    assert b.over()
    assert not Budget(None).over(ahead=1e9)
