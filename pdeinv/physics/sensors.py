"""Sensor time series of any time-stepping operator, with exact discrete adjoints.

``sensors(op, S, k)`` observes the run of ``op`` (a :class:`~pdeinv.Heat`,
:class:`~pdeinv.Wave` or :class:`~pdeinv.Leapfrog`) through the sensor matrix ``S``
(``n_s × N``, :func:`pdeinv.observe.sensor_matrix`) after every ``k``-th step:
the same scheme and factorization, another observation (:mod:`.observation`
documents the record-major layout of ``y``; :mod:`.propagator` the reverse sweep
that gives the adjoint). Cost: forward and adjoint are one run each, plus a sparse
``S`` product per record.
"""

from __future__ import annotations


def sensors(op, S, record_every: int = 1):
    """The sensor operator of ``op``'s run: ``S u`` after every ``record_every``-th step."""
    make = getattr(op, "sensors", None)
    if make is None:
        raise ValueError(f"{op!r} is not a time-stepping operator; sensors need Heat, Wave or Leapfrog")
    return make(S, record_every)


#: the names sensor scenes used before the one propagator (same call)
HeatSensors = WaveSensors = sensors
