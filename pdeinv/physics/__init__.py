"""Linear evolution operators with exact discrete adjoints: scheme × observation, one propagator."""

from .backends.modal import Modal
from .base import LinearOperator, Matrix, Transposed
from .heat import Heat
from .leapfrog import Leapfrog
from .nonlinear import Physics
from .propagator import FinalField, Propagator, Records, sensors
from .reaction import ReactionHeat
from .sine_gordon import SineGordon
from .wave import Wave

#: the names the sensor scenes used before the one propagator (same call; public in ``pdeinv``)


def Stepping(op) -> Propagator:  # noqa: N802 - the name of the former stepping backend class
    """``op``'s run applied by time stepping (:meth:`Propagator.stepping`)."""
    return op.stepping()


__all__ = ["LinearOperator", "Matrix", "Transposed", "Heat", "Leapfrog", "Modal", "Stepping", "Wave",
           "FinalField", "Propagator", "Records", "sensors", "Physics", "ReactionHeat", "SineGordon"]
