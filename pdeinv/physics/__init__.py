"""Linear evolution operators with exact discrete adjoints: scheme × observation, one propagator."""

from .base import LinearOperator, Matrix, Transposed
from .heat import Heat
from .heat_backends import Modal, Stepping
from .leapfrog import Leapfrog
from .observation import FinalField, Records
from .propagator import Propagator
from .sensors import HeatSensors, WaveSensors, sensors
from .wave import Wave

__all__ = ["LinearOperator", "Matrix", "Transposed", "Heat", "Leapfrog", "Modal", "Stepping", "Wave",
           "FinalField", "Records", "Propagator", "HeatSensors", "WaveSensors", "sensors"]
