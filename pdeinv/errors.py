"""The two kinds of failure a user meets, and how the command line reports them.

* **Bad input** (a setting, a file, a shape a user can fix): ``ValueError`` and its
  subclasses, ``FileNotFoundError``; the CLI prints one line and exits with 2.
* **Numerical failure** (the input was valid, the computation was not: non-finite
  values, a solver that did not converge, a representation that would need too
  many modes): :class:`NumericalError`; the CLI prints one line that says what to
  change and exits with 1. ``numpy.linalg.LinAlgError`` (a ``ValueError`` in numpy)
  and ``scipy.sparse.linalg.ArpackNoConvergence`` count as numerical failures too.
"""

from __future__ import annotations


class NumericalError(RuntimeError):
    """A numerical failure on valid input; the message says what to change."""


class NonFiniteError(NumericalError):
    """A loss or an update contained NaN or Inf; the parameters were left untouched. ``overshoot``:
    the factor to cut the step size by beyond the usual one (a finite blow-up's), or None."""

    overshoot: float | None = None


class TooManyModes(NumericalError):
    """The modal representation would need a large fraction of all modes."""


class ConvergenceError(NumericalError):
    """An iterative solver did not reach its tolerance."""


def numerical_types() -> tuple[type[BaseException], ...]:
    """Exception types reported as numerical failures (exit 1), including numpy's and ARPACK's."""
    import numpy as np
    from scipy.sparse.linalg import ArpackNoConvergence

    return (NumericalError, np.linalg.LinAlgError, ArpackNoConvergence)
