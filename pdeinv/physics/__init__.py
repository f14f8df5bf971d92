"""Linear evolution operators with exact discrete adjoints: scheme × observation, one propagator."""

from .base import LinearOperator, Matrix, Transposed
from .heat import Heat
from .heat_backends import Modal, Stepping
from .leapfrog import Leapfrog
from .propagator import FinalField, Propagator, Records, sensors
from .wave import Wave

#: the names the sensor scenes used before the one propagator (same call)
HeatSensors = WaveSensors = sensors

__all__ = ["LinearOperator", "Matrix", "Transposed", "Heat", "Leapfrog", "Modal", "Stepping", "Wave",
           "FinalField", "Propagator", "Records", "HeatSensors", "WaveSensors", "sensors"]
