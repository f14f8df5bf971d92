"""Benchmarks: run time against error, ratios, skips (``pdeinv bench``); stress sweeps (``pdeinv stress``).

One idea per module, all on the public API: :mod:`.timing`, :mod:`.ratios` (operator and step
costs), :mod:`.backends`, :mod:`.forward` (accuracy/cost ladder against exact solutions),
:mod:`.methods` (the presets at equal wall-clock time), :mod:`.amortize`, :mod:`.skips`,
:mod:`.plots`, :mod:`.run` (all of it into ``bench.json``), :mod:`.stress` with :mod:`.cases`.
Developer benchmarks that ``pdeinv bench`` does not run are scripts in the top-level ``benchmarks/``.
"""

from .ratios import operator_ratios
from .run import bench, summary

__all__ = ["bench", "operator_ratios", "summary"]
