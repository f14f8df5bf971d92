"""Linear evolution operators with exact discrete adjoints."""

from .base import LinearOperator, Matrix, Transposed
from .heat import Heat
from .heat_backends import Modal, Stepping
from .wave import Wave

__all__ = ["LinearOperator", "Matrix", "Transposed", "Heat", "Modal", "Stepping", "Wave"]
