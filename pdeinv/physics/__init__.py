"""Linear evolution operators with exact discrete adjoints."""

from .base import LinearOperator, Matrix, Transposed
from .heat import Heat
from .heat_backends import Modal, Stepping
from .leapfrog import Leapfrog
from .sensors import HeatSensors, WaveSensors
from .wave import Wave

__all__ = ["LinearOperator", "Matrix", "Transposed", "Heat", "Leapfrog", "Modal", "Stepping", "Wave",
           "HeatSensors", "WaveSensors"]
