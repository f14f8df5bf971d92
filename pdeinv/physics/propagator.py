"""One loop for every time-stepping operator (Heat, Wave, Leapfrog, sensor runs): scheme × observation.

With the scheme's ``s₀ = I x``, ``sⱼ = S sⱼ₋₁``, ``uⱼ = E sⱼ`` (:mod:`.schemes`) and
records ``y_r = O u_{(r+1)k}`` after every ``k``-th of ``n`` steps (``O`` the sensor
matrix, or the identity), the forward map and its exact discrete transpose are

    forward:  s = I x;  for j = 1…n:  s = S s;  record O E s if k divides j
    adjoint:  s̄ = 0;   for j = n…1:  s̄ += Eᵀ Oᵀ r_j if k divides j;  s̄ = Sᵀ s̄;   x̄ = Iᵀ s̄

(a reverse sweep, no stored trajectory: the map is linear); all batch columns go
through each step together. **Layout of y (record-major):** ``y[b, r·n_s + s]`` is
sensor ``s`` at ``t_r = (r+1)·k·dt``; ``y.reshape(B, R, n_s)`` gives the time series.

The output space is declared, never guessed from shapes (:mod:`.capabilities`):
:class:`FinalField` observes a field on the mesh, :class:`Records` plain numbers.

How the map is applied is chosen once, by :meth:`Propagator.compile` (the one chooser,
:func:`.compiled.plan`): time stepping, a dense matrix, a truncated SVD, or the modal form of a
symmetric θ-scheme (:mod:`.modal`). An operator no one chose for is compiled by ``auto`` when it
becomes part of a :class:`pdeinv.Problem` or gets its local inverse (:func:`chosen`).
"""

from __future__ import annotations

import numpy as np

from .._checks import batch, count
from .._checks import choice as one_of
from .base import LinearOperator
from .capabilities import Spectral


class Records:
    """``O u`` after every ``every``-th of ``steps`` steps; ``O = S`` (``n_s × n``) or the identity."""

    space = "records"

    def __init__(self, S, n: int, steps: int, every: int = 1):
        if S is not None and (S.shape[1] != n or S.shape[0] == 0):
            raise ValueError(f"sensor matrix has shape {S.shape}; expected (n_sensors >= 1, {n})")
        self.S, self.ST = (None, None) if S is None else (S.tocsr(), S.T.tocsr())
        self.every = count(every, "record_every")
        if steps % self.every:
            div = [d for d in range(1, steps + 1) if steps % d == 0]
            raise ValueError(f"record_every={every!r} does not divide steps={steps}; allowed: a divisor of "
                             f"steps ({', '.join(map(str, div[:12]))}{', …' if len(div) > 12 else ''}), so "
                             "that records are uniform in time and include the final field")
        self.n_records, self.n_sensors = steps // self.every, n if S is None else S.shape[0]
        self.n_out = self.n_sensors * self.n_records

    def _slot(self, j: int) -> slice:
        r = j // self.every - 1
        return slice(r * self.n_sensors, (r + 1) * self.n_sensors)

    def write(self, Y: np.ndarray, j: int, U: np.ndarray) -> None:
        """Store ``O U`` into ``Y`` if step ``j`` (1-based) is recorded."""
        if j % self.every == 0:
            Y[:, self._slot(j)] = (U if self.S is None else self.S @ U).T

    def read_T(self, R: np.ndarray, j: int):
        """``Oᵀ r_j`` as ``(n, B)`` if step ``j`` is recorded, else ``None`` (transposes :meth:`write`)."""
        if j % self.every:
            return None
        Rj = R[:, self._slot(j)].T
        return Rj if self.ST is None else self.ST @ Rj


class FinalField(Records):
    """The field after the last step: ``y = u_n``."""

    space = "field"

    def __init__(self, n: int, steps: int):
        super().__init__(None, n, steps, every=steps)


class Propagator(LinearOperator):
    """``steps`` steps of ``scheme`` from ``x``, recorded by ``observation`` (module docstring);
    ``mass``: the mass matrix of the unknowns. ``backend``: a compiled backend or None (time
    stepping); ``choice``: why, or None while no backend was chosen (:func:`chosen`)."""

    #: relative gain below which the modal form drops a mode (:mod:`.modal`)
    tol = 1e-14

    def __init__(self, scheme, observation: Records, steps: int, mass=None):
        self.scheme, self.observation, self.steps, self.mass = scheme, observation, int(steps), mass
        self.n_in, self.n_out = scheme.n, observation.n_out
        self.backend, self.choice = None, None

    def compile(self, kind: str = "auto", M=None) -> Propagator:
        """Apply ``P`` through a compiled backend: 'dense', 'svd' (in the norms of ``M``, default
        ``self.mass``; Euclidean for records), 'modal' (a symmetric θ-scheme's final field, in its own
        mass, :mod:`.modal`), 'steps' (none) or 'auto' (:func:`.compiled.plan` by the cost of a run)."""
        from ..errors import TooManyModes
        from .backends import modal
        from .backends.compiled import build, fingerprint, in_cache, plan
        from .capabilities import reversible

        kind = one_of(kind, "backend", ("auto", "steps", "modal", "dense", "svd"))
        why = f"backend={kind!r} requested"
        M = self.mass if M is None else M
        M_out, parts = (M if self.output_space == "field" else None), fingerprint(self)
        if kind == "auto":
            costs = (self.step_flops(), self.n_in, self.n_out, reversible(self),
                     in_cache(parts, M, M_out, self.n_in, self.n_out))
            kind, why = plan(*costs, modal=modal.estimate(self))
            if kind == "modal":
                try:
                    return self._modal(why)
                except (TooManyModes, ValueError) as err:
                    kind, why = plan(*costs)
                    why = f"{why}; modal refused: {err}"
        if kind == "modal":
            return self._modal(why)
        # an undamped (time-reversible) map with m ≥ N keeps every input direction: no low-rank try
        low_rank = not (reversible(self) and self.n_out >= self.n_in)
        return self._use(None if kind == "steps" else build(
            kind, self._step_forward, self.n_in, self.n_out, M, M_out, parts,
            adjoint=self._step_adjoint if low_rank else None), why)

    def _modal(self, why: str) -> Propagator:
        from .backends.modal import Modal

        basis = Modal(self)
        return self._use(basis, f"{why}; {basis.k} of {self.n_in} modes kept")

    def _use(self, backend, why: str) -> Propagator:
        self.backend, self.choice = backend, why
        return self

    def step_flops(self) -> float:
        """Flops of one column through the whole run (the one step-cost model): ``steps`` times the
        scheme's declared cost of a step (``scheme.flops()``, :mod:`.schemes`)."""
        return self.steps * self.scheme.flops()

    def forward_flops(self) -> float:
        """One column's forward: :meth:`step_flops` when stepping, else the compiled backend's products
        (its ``flops()``) discounted by :data:`~.backends.compiled.BLAS_ADVANTAGE`."""
        from .backends.compiled import BLAS_ADVANTAGE

        return self.step_flops() if self.backend is None else self.backend.flops() / BLAS_ADVANTAGE

    def count_modes(self, mu: float) -> float:
        """How many eigenvalues of the scheme's ``L φ = λ M φ`` lie below ``mu`` (sizes the modal
        eigensolve): exact for a symmetric θ-scheme beyond ``modes.DENSE_MAX`` unknowns
        (:meth:`exact_count`), else all ``N`` (:class:`~pdeinv.physics.Heat`: Weyl's law there)."""
        exact = self.exact_count(mu)
        return float(self.n_in) if exact is None else float(exact)

    def exact_count(self, mu: float) -> int | None:
        """The number of eigenvalues of ``L φ = λ M φ`` below ``mu`` by Sylvester's inertia
        (:func:`.modes.count_below`, one sparse LU, cached per ``mu``) for a symmetric θ-scheme beyond
        ``modes.DENSE_MAX`` unknowns (where the dense eigh, which needs no count, is not used); else
        None."""
        from .backends import modes
        from .schemes import Theta

        if not (isinstance(self.scheme, Theta) and self.symmetric and self.n_in > modes.DENSE_MAX):
            return None
        counted = self.__dict__.setdefault("_counts", {})
        if mu not in counted:
            counted[mu] = None  # no exact count (the callers fall back to theirs) if both tries fail
            for shift in (1.0, 1.0 + 1e-9):  # an exactly zero pivot (mu an eigenvalue): move mu off it
                try:
                    counted[mu] = modes.count_below(self.scheme.M, self.scheme.L, mu * shift)
                    break
                except RuntimeError:  # SuperLU: "Factor is exactly singular"
                    continue
        return counted[mu]

    def stepping(self) -> Propagator:
        """The same run applied by time stepping (no compiled backend): ``self`` if it steps."""
        return self if self.backend is None else Propagator(self.scheme, self.observation, self.steps,
                                                            self.mass)._use(None, "stepping")

    @property
    def reversible(self) -> bool:
        """Declared by the scheme (:mod:`.schemes`: Newmark, leapfrog) for the final field: the
        full final state is run back to the initial one by :meth:`reverse`."""
        return bool(self.scheme.reversible) and self.observation.space == "field"

    def final_state(self, U0, C0=None) -> tuple[np.ndarray, np.ndarray]:
        """``(u_T, c_T)`` from ``u₀`` (and its companion ``c₀``; default: the scheme's start from rest),
        batch-first; the companion is the scheme's other half of the state (Newmark: the velocity
        ``v``; leapfrog: the previous step's displacement)."""
        return self._run(U0, C0, 1.0, ("U0", "C0"))

    def reverse(self, UT, CT) -> tuple[np.ndarray, np.ndarray]:
        """Step back from ``(u_T, c_T)`` to ``(u₀, c₀)``: the scheme's reversed step, ``steps`` times."""
        if CT is None:
            raise ValueError("reverse needs the final state's companion c_T (final_state gives it)")
        return self._run(UT, CT, -1.0, ("UT", "CT"))

    def _run(self, U, C, sign: float, names: tuple[str, str]):
        if not self.reversible:
            raise ValueError(f"{self!r} is not time-reversible: its scheme ({type(self.scheme).__name__}) "
                             "does not declare it, or it does not observe the final field")
        U, single = batch(U, self.n_in, names[0])
        if C is None:
            s = self.scheme.start(U.T)
        else:
            C = batch(C, self.n_in, names[1])[0]
            if C.shape != U.shape:
                raise ValueError(f"{names[1]} has shape {C.shape}; expected {names[0]}'s {U.shape}")
            s = self.scheme.pack(U.T, C.T)
        out = tuple(np.ascontiguousarray(a.T) for a in self.scheme.unpack(self._march(s, sign=sign)))
        return tuple(a[0] for a in out) if single else out

    kind = property(lambda self: "steps" if self.backend is None else self.backend.name)
    modes = property(lambda self: self.backend if isinstance(self.backend, Spectral) else None)
    output_space = property(lambda self: self.observation.space)
    symmetric = property(lambda self: bool(self.scheme.symmetric))
    dt = property(lambda self: self.scheme.dt)
    S = property(lambda self: self.observation.S)
    n_sensors = property(lambda self: self.observation.n_sensors)
    n_records = property(lambda self: self.observation.n_records)
    record_every = property(lambda self: self.observation.every)

    def times(self, dt: float | None = None) -> np.ndarray:
        """Time of each record, ``(r+1)·k·dt``."""
        return (np.arange(self.n_records) + 1) * self.record_every * (self.dt if dt is None else dt)

    def sensors(self, S, record_every: int = 1) -> Propagator:
        """The same scheme (and factorization) observed through ``S`` every ``record_every`` steps."""
        return Propagator(self.scheme, Records(S, self.n_in, self.steps, record_every), self.steps, self.mass)

    def _forward(self, X):
        return self._step_forward(X) if self.backend is None else self.backend.forward(X)

    def _adjoint(self, R):
        return self._step_adjoint(R) if self.backend is None else self.backend.adjoint(R)

    def _march(self, s, record=None, sign: float = 1.0):
        """The state after all steps from ``s`` (``sign=-1``: backwards, a reversible scheme),
        calling ``record(j, s)`` after step ``j``: the one time loop forward."""
        step = self.scheme.step if sign == 1.0 else (lambda state: self.scheme.step(state, sign))
        for j in range(1, self.steps + 1):
            s = step(s)
            if record is not None:
                record(j, s)
        return s

    def _step_forward(self, X):
        sc, obs = self.scheme, self.observation
        Y = np.empty((X.shape[0], self.n_out))
        self._march(sc.start(X.T), lambda j, s: obs.write(Y, j, sc.field(s)))
        return Y

    def _step_adjoint(self, R):
        sc, obs = self.scheme, self.observation
        s = sc.zeros(self.n_in, R.shape[0])
        for j in range(self.steps, 0, -1):
            W = obs.read_T(R, j)
            s = s if W is None else sc.inject(s, W)
            s = sc.step_T(s)
        return np.ascontiguousarray(sc.start_T(s).T)

    def __repr__(self):
        obs = self.observation
        what = "final field" if obs.space == "field" else (
            f"sensors={obs.n_sensors}, records={obs.n_records}, record_every={obs.every}")
        return f"Propagator({type(self.scheme).__name__}, N={self.n_in}, steps={self.steps}, {what})"


def sensors(op, S, record_every: int = 1) -> Propagator:
    """``op``'s run (Heat, Wave, Leapfrog: any :class:`Propagator`) observed through ``S``."""
    if not isinstance(op, Propagator):
        raise ValueError(f"{op!r} is not a time-stepping operator; sensors need Heat, Wave or Leapfrog")
    return op.sensors(S, record_every)


def chosen(op, M=None):
    """``op`` with a backend chosen: compiled by ``auto`` (in the norms of ``M``) if it is a
    time-stepping operator no one chose a backend for (``choice`` None), else as it is. Called by
    :class:`pdeinv.Problem` and :func:`pdeinv.inverse.default_inverse`, so that an operator built
    by hand (``Heat(...).sensors(S, k)``, ``Wave(...)``) runs at the speed the scenes do."""
    if isinstance(op, Propagator) and op.choice is None:
        op.compile("auto", M)
    return op
