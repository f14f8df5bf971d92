"""Benchmarks: run time against error, ratios, skips (``pdeinv bench``); stress sweeps (``pdeinv stress``).

One idea per module: :mod:`.timing` (minimum-of-repeats timer, peak memory, machine),
:mod:`.ratios` (operator costs against bare scipy), :mod:`.steps` (update-rule step
costs), :mod:`.forward` (accuracy/cost ladder against exact solutions),
:mod:`.methods` (rules at equal wall-clock time), :mod:`.skips` (what each skip
saves), :mod:`.plots`, :mod:`.run` (all of it into ``bench.json``), and
:mod:`.stress` with :mod:`.cases` (sweeps that try to break things).
"""

from .ratios import operator_ratios
from .run import bench, summary

__all__ = ["bench", "operator_ratios", "summary"]
