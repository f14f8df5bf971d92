"""One loop for every time-stepping operator: scheme × observation (× the scheme's solver).

With the scheme's ``s₀ = I x``, ``sⱼ = S sⱼ₋₁``, ``uⱼ = E sⱼ`` (:mod:`.schemes`) and
the observation's records ``y_r = O u_{(r+1)k}`` (:mod:`.observation`), the forward
map and its exact discrete transpose are

    forward:  s = I x;  for j = 1…n:  s = S s;  record O E s if j is recorded
    adjoint:  s̄ = 0;   for j = n…1:  s̄ += Eᵀ Oᵀ r_j if j is recorded;  s̄ = Sᵀ s̄;   x̄ = Iᵀ s̄

(a reverse sweep, no stored trajectory: the map is linear). All batch columns go
through each step together (one solve with ``b`` right-hand sides).

Capabilities other code chooses by (never by concrete class, see
:mod:`.capabilities`): ``output_space`` ("field": a field on the mesh, measured
with its mass matrix; "records": plain numbers, Euclidean), ``symmetric`` (every
matrix of the scheme is), and, for reversible schemes, ``final_state`` /
``reverse`` (:class:`~pdeinv.Wave`).
"""

from __future__ import annotations

import numpy as np

from .base import LinearOperator
from .observation import FinalField, Records


class Propagator(LinearOperator):
    """``steps`` steps of ``scheme`` from ``x``, recorded by ``observation`` (module docstring).

    ``mass``: the mass matrix of the unknowns (what measures a field observation).
    """

    def __init__(self, scheme, observation: Records, steps: int, mass=None):
        self.scheme, self.observation = scheme, observation
        self.steps = int(steps)
        self.n_in, self.mass = scheme.n, mass
        self.n_out = observation.n_out

    @property
    def output_space(self) -> str:
        return self.observation.space

    @property
    def dt(self) -> float:
        return self.scheme.dt

    @property
    def symmetric(self) -> bool:
        return bool(self.scheme.symmetric)

    def with_observation(self, observation: Records) -> Propagator:
        """The same scheme (and factorization) observed differently."""
        return Propagator(self.scheme, observation, self.steps, self.mass)

    def sensors(self, S, record_every: int = 1) -> Propagator:
        """Records ``S u`` every ``record_every`` steps (:class:`~.observation.Records`)."""
        return self.with_observation(Records(S, self.n_in, self.steps, record_every))

    def _forward(self, X):
        sc, obs = self.scheme, self.observation
        Y = np.empty((X.shape[0], self.n_out))
        s = sc.start(X.T)
        for j in range(1, self.steps + 1):
            s = sc.step(s)
            obs.write(Y, j, sc.field(s))
        return Y

    def _adjoint(self, R):
        sc, obs = self.scheme, self.observation
        s = sc.zeros(self.n_in, R.shape[0])
        for j in range(self.steps, 0, -1):
            W = obs.read_T(R, j)
            if W is not None:
                s = sc.inject(s, W)
            s = sc.step_T(s)
        return np.ascontiguousarray(sc.start_T(s).T)

    # -- what sensor operators used to expose ----------------------------------------------
    @property
    def S(self):
        """The observation matrix (``None``: the field itself)."""
        return self.observation.S

    @property
    def n_sensors(self) -> int:
        return self.observation.n_sensors

    @property
    def n_records(self) -> int:
        return self.observation.n_records

    @property
    def record_every(self) -> int:
        return self.observation.every

    def times(self, dt: float | None = None) -> np.ndarray:
        """Time of each record (with the scheme's ``dt`` unless given)."""
        return self.observation.times(self.dt if dt is None else dt)

    def __repr__(self):
        obs = self.observation
        what = ("final field" if isinstance(obs, FinalField) else
                f"sensors={obs.n_sensors}, records={obs.n_records}, record_every={obs.every}")
        return (f"{type(self).__name__}({type(self.scheme).__name__}, N={self.n_in}, "
                f"steps={self.steps}, {what})")
