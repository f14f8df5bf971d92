"""pdeinv: PDE inverse problems on finite elements.

The pipeline, upstream to downstream: mesh → forms → physics (operators with
exact adjoints) → autograd bridge / inverse simulators → update rules → trainer.
"""

from . import mesh
from .autograd import apply
from .forms import Discretization, discretize
from .inverse import (
    Discrepancy,
    FixedAlpha,
    ModalTikhonov,
    RelativeAlpha,
    StateReversal,
    TikhonovCG,
    TimeReversal,
    default_inverse,
)
from .physics import Heat, LinearOperator, Matrix, Modal, Stepping, Wave
from .problem import Problem, available, load_problem
from .solvers import AMGCG, Cholesky, SuperLU, amg_cg, default_solver

__all__ = [
    "Discrepancy",
    "FixedAlpha",
    "ModalTikhonov",
    "RelativeAlpha",
    "StateReversal",
    "TikhonovCG",
    "TimeReversal",
    "default_inverse",
    "AMGCG",
    "Cholesky",
    "Discretization",
    "Heat",
    "LinearOperator",
    "Matrix",
    "Modal",
    "Problem",
    "Stepping",
    "SuperLU",
    "Wave",
    "amg_cg",
    "apply",
    "default_solver",
    "available",
    "discretize",
    "load_problem",
    "mesh",
]
__version__ = "0.1.0"
