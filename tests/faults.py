"""Injected faults for the NaN/Inf guard: a problem module whose operator returns NaN on chosen calls.

``load_problem("tests/faults.py", poison="3,4", batch=8)`` is heat_1d (modal backend)
whose forward map returns NaN on the 3rd and 4th *training* calls, i.e. calls with
exactly ``batch`` rows (samples and test sets have other sizes). GD and SIP call the
forward map once per attempted step, so call k is the k-th attempted step.
"""

import numpy as np

from pdeinv import load_problem
from pdeinv.physics.base import LinearOperator


class Poisoned(LinearOperator):
    def __init__(self, op, calls, batch):
        self.op, self.calls, self.batch, self.count = op, set(calls), batch, 0
        self.n_in, self.n_out = op.n_in, op.n_out

    def _forward(self, X):
        Y = self.op.forward(X)
        if X.shape[0] == self.batch:
            self.count += 1
            if self.count in self.calls:
                return np.full_like(Y, np.nan)
        return Y

    def _adjoint(self, R):
        return self.op.adjoint(R)


def make(poison="", batch="8", **overrides):
    problem = load_problem("heat_1d", backend="modal", **overrides)
    calls = [int(c) for c in str(poison).split(",") if c.strip()]
    problem.operator = Poisoned(problem.operator, calls, int(batch))
    problem.settings = {**problem.settings, "poison": str(poison)}
    return problem
