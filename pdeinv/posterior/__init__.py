"""Posteriors: what an estimate does not know.

* :mod:`.gaussian`: the exact linear-Gaussian posterior, low-rank through the adjoint (the reference);
* :mod:`.conformal`: a trained network's calibrated posterior (split-conformal on held-out rows);
* :mod:`.diagnostics`: coverage, credible balls and simulation-based calibration on test rows.
"""

from .gaussian import GaussianPrior, LinearGaussian

__all__ = ["GaussianPrior", "LinearGaussian"]
