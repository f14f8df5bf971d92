"""pdeinv: PDE inverse problems on finite elements.

The pipeline, upstream to downstream: mesh → forms → physics (operators with
exact adjoints) → autograd bridge / inverse simulators → update rules → trainer.
"""

from . import export, mesh, observe, plots, runs
from .autograd import apply
from .checkpoint import Checkpoint
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
from .methods import GD, HIG, SIP, NonFiniteError, adam, sgd
from .nets import Net, mlp, whitened
from .noise import estimate_noise
from .observe import sensor_matrix
from .physics import Heat, HeatSensors, Leapfrog, LinearOperator, Matrix, Modal, Stepping, Wave, WaveSensors
from .precondition import Whitening
from .problem import Problem, available, load_problem
from .runs import load_run, save_run
from .solvers import AMGCG, Cholesky, SuperLU, amg_cg, default_solver
from .stopping import DiscrepancyStop
from .train import Result, Trainer, train

__all__ = [
    "Checkpoint",
    "GD",
    "HIG",
    "SIP",
    "NonFiniteError",
    "Result",
    "Trainer",
    "adam",
    "mlp",
    "Net",
    "whitened",
    "Whitening",
    "DiscrepancyStop",
    "estimate_noise",
    "sgd",
    "train",
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
    "HeatSensors",
    "Leapfrog",
    "LinearOperator",
    "Matrix",
    "Modal",
    "Problem",
    "Stepping",
    "SuperLU",
    "Wave",
    "WaveSensors",
    "amg_cg",
    "apply",
    "default_solver",
    "available",
    "discretize",
    "load_problem",
    "load_run",
    "save_run",
    "runs",
    "export",
    "mesh",
    "observe",
    "plots",
    "sensor_matrix",
]
__version__ = "0.1.0"
