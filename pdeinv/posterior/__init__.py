"""Posteriors: what an estimate does not know.

* :mod:`.gaussian`: the exact linear-Gaussian posterior, low-rank through the adjoint (the reference);
* :mod:`.conformal`: a trained network's calibrated posterior (split-conformal on held-out rows);
* :mod:`.diagnostics`: coverage, credible balls and simulation-based calibration on test rows;
* :mod:`.predictive`: mean, std, intervals and samples of new observations;
* :mod:`.stage`: the calibration stage of a training run.
"""

from .conformal import Calibration
from .gaussian import GaussianPrior, LinearGaussian
from .predictive import predictive
from .stage import CalibrationStage

__all__ = ["Calibration", "CalibrationStage", "GaussianPrior", "LinearGaussian", "predictive"]
