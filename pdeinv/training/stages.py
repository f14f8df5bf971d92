"""The stages of a run after the rule's: what a prior adds where the observations cannot decide.

A run is the rule's stage (the trainer's loop: GD, SIP, HIG, … train the network through the physics)
followed, where the network has a part fitted on the prior (:class:`pdeinv.nets.refine.PriorFitted`) and a
prior is available (the scene's sampler, or the ``x`` rows of the user's file), by the :class:`PriorStage`:
its correction is fitted on prior draws and its data-consistency layer gives the observations back
(:mod:`pdeinv.nets.consistency`). Every budget is a count (draws, steps); each stage reports its own
held-out x- and y-errors and seconds in ``metrics["stages"]``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from ..nets.refine import PriorFit, PriorFitted, Refined
from .trainset import prior_rows

#: prior draws for the stage's decision, before any fitting (their own seed stream)
PILOT = 64

#: a base whose relative error on the pilot draws is below this leaves the prior too little to add: the
#: float32 corrections were never kept below it (noise-free heat_2d 0.0016, heat_plate 0.0020, heat_1d
#: 0.0040, wave_2d 5e-9, each after 6–180 s of fitting), and they gain 2–4× where the base is above it
NEGLIGIBLE = 0.01

#: prior draws of a default stage: at most this many field entries (x and y, float64: ~320 MB) and
#: :data:`MOST_DRAWS` rows, never fewer than :data:`FEWEST_DRAWS` or than :data:`ENTRIES_4K` allows
ENTRIES, MOST_DRAWS, FEWEST_DRAWS = 20_000_000, 65_536, 256
#: at 10⁴–10⁵ unknowns one U-Net step takes seconds and a fit sees a few thousand draws at most
ENTRIES_4K = 50_000_000


#: multiply-adds a default stage's fit may spend (forward and backward, ~3× a forward pass per draw), a
#: count, the same on every machine: ~1 000 U-Net steps of 32 draws on heat_boxes' 63×63 grid (0.64 s each
#: on one core, ~1.5·10¹⁰ multiply-adds per second), which reach 0.042 there; half of it reached 0.050
FIT_MACS = 9e12


def step_count(problem, kind: str, batch: int, n_train: int, fit: PriorFit) -> int:
    """The stage's fitting steps: ``fit.steps`` if set, else the fewer of ``fit``'s passes over the
    ``n_train`` training draws and what :data:`FIT_MACS` buys at :func:`~pdeinv.nets.corrections.
    correction_macs` per draw."""
    from ..nets.corrections import correction_macs
    from ..physics.capabilities import modal_basis

    if fit.steps is not None:
        return fit.steps
    macs = correction_macs(kind, problem.N, problem.operator.n_out, problem.points.shape[0],
                           modal_basis(problem.operator) is not None)
    return int(max(1, min(fit.step_count(n_train, batch), FIT_MACS // (3 * macs * batch))))


def draw_count(N: int) -> int:
    """The default stage's prior draws for ``N`` unknowns: ``min(65 536, 2·10⁷/N)``, at least
    ``min(4 096, 5·10⁷/N)`` and 256 (heat_boxes 64²: 5 039; heat_1d: 65 536; 30 k unknowns: 1 670).
    A dense correction on 4 096 sine_gordon_1d draws early-stopped at 0.094, on 16 384 it reached 0.064."""
    N = max(int(N), 1)
    return int(max(FEWEST_DRAWS, min(4096, ENTRIES_4K // N), min(MOST_DRAWS, ENTRIES // N)))


@dataclass(frozen=True)
class PriorStage:
    """Fit a network's prior part on ``draws`` prior pairs (``None``: :func:`draw_count`) with ``fit``'s
    settings (:class:`~pdeinv.nets.refine.PriorFit`, seeded with the run's seed; its steps, when not set,
    :func:`step_count`). Decided against before it fits (:meth:`why_not`) when the data carry no prior, or
    when the rule's estimate is already within :data:`NEGLIGIBLE` of :data:`PILOT` prior draws."""

    fit: PriorFit = field(default_factory=PriorFit)
    draws: int | None = None
    name: str = "prior"

    def __post_init__(self):
        if not isinstance(self.fit, PriorFit):
            raise TypeError(f"PriorStage(fit={self.fit!r}) is not allowed; expected a "
                            "pdeinv.nets.refine.PriorFit")
        if self.draws is not None and (isinstance(self.draws, bool) or not isinstance(self.draws, int)
                                       or self.draws < 2):
            raise ValueError(f"PriorStage(draws={self.draws!r}) is not allowed; expected an integer >= 2 or "
                             "None (the default count)")

    def applies(self, model) -> bool:
        return isinstance(model, PriorFitted)

    def draw_count(self, problem) -> int:
        return self.draws if self.draws is not None else draw_count(problem.N)

    def planned(self, problem, kind: str, own=None) -> dict:
        """What the stage will do for a correction of ``kind`` (:func:`pdeinv.nets.defaults.correction_kind`),
        before anything is built (:func:`pdeinv.training.plan.plan`)."""
        from ..nets.corrections import fit_batch
        from ..physics.capabilities import modal_basis

        if own is not None and own.x is None:
            return {"name": self.name, "skipped": "no prior: the data file has no x"}
        n = len(own.x) if own is not None else self.draw_count(problem)
        batch = self.fit.batch or fit_batch(kind, problem.N, problem.points.shape[0])
        n_train = n - max(1, round(self.fit.held_out * n))
        steps = step_count(problem, kind, batch, n_train, self.fit)
        source = ("the data file's x" if own is not None
                  else problem.settings.get("prior", "the scene's sampler"))
        names = {"grid": "a U-Net on the grid", "dense": "a dense MLP",
                 "span": "an MLP in the decoder's span"}
        return {"name": self.name, "draws": n, "max_steps": steps,
                "batch": batch,
                "correction": names.get(kind, kind), "prior": source,
                "consistency": modal_basis(problem.operator) is not None}

    def why_not(self, problem, model, own, seed: int, relative_error) -> str | None:
        """Why the stage cannot help, from :data:`PILOT` prior draws (no fitting), or ``None``."""
        pilot, source = prior_rows(problem, own, PILOT, seed, stream=1)
        if pilot is None:
            return f"no prior: {source}"
        x, y = pilot[0][:PILOT], pilot[1][:PILOT]
        dtype = next(model.parameters()).dtype
        with torch.no_grad():
            xb = model(torch.as_tensor(y, dtype=dtype)).double().numpy()
        err = float(np.mean(relative_error(xb, x)))
        if err <= NEGLIGIBLE:
            return (f"the rule's estimate is within {err:.2g} of {len(x)} prior draws (relative L2 error, at "
                    f"most {NEGLIGIBLE:g}): too little is left for the prior")
        return None

    def run(self, problem, model, own, seed: int) -> dict:
        """Draw, fit, and say what was done (``kept``, ``draws``, ``steps``, held-out errors, ``prior``)."""
        t0 = time.perf_counter()
        draws, source = prior_rows(problem, own, self.draw_count(problem), seed)
        if draws is None:
            return {"kept": False, "skipped": f"no prior: {source}", "prior": source}
        fit = replace(self.fit, seed=seed)
        if isinstance(model, Refined):  # a user's own PriorFitted network counts its own steps
            n = len(draws[0])
            batch = self.fit.batch or model.correction.fit_batch
            held = max(1, round(self.fit.held_out * n))
            fit = replace(fit, steps=step_count(problem, model.correction_kind, batch, n - held, self.fit))
        info = fit.fit(model, *draws, problem.relative_error)
        return {**info, "prior": source, "seconds": time.perf_counter() - t0}
