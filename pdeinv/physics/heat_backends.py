"""Former home of the heat backends (now :mod:`.modal` and :meth:`.propagator.Propagator.compile`).

Kept only for ``pdeinv.bench.forward``, which imports :func:`weyl_count` from here, until the
bench moves to the public API (issue 24, item 4).
"""

from .modal import weyl_count

__all__ = ["weyl_count"]
