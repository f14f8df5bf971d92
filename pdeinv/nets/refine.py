"""A nonlinear correction of a network's estimate, fitted on draws of the prior: what no linear
estimator can do.

Physics-based rules (GD, SIP, HIG) see ``x`` only through ``y = P x``: the part of ``x`` the physics
destroys (heat's fine scales below rounding, a sensor set's blind spots) receives no gradient, so a
network trained by them alone fills it with whatever its architecture implies, at best the linear
MMSE's Gaussian guess. Where the prior is not Gaussian (the SIP paper's boxes: jumps) the conditional
mean of those parts given the visible ones is nonlinear, and the only source of it is the prior
itself. :class:`Refined` is therefore

    f(y) = b_λ(y) + g(y, b(y)),   b_λ = b + λ (x_T − b),

``b`` the base network (trained by the rule, e.g. SIP: the whitened linear map or the prior
decoder), ``x_T`` the physics' own full-rank Tikhonov estimate where the correction has one
(:class:`~pdeinv.nets.corrections.SpectralFilter`; else ``λ = 0``), ``λ`` the least-squares blend of the two
on the training draws (closed form, ``λ = Σ⟨x − b, x_T − b⟩ / Σ‖x_T − b‖²``): the correction starts from
the better of the two linear estimates, not from ``b`` alone, which is learned from the training rows and
has at most their rank (heat_boxes at 95² unknowns: ``b`` at 0.600, ``x_T`` at ~0.11); ``g`` a correction
strategy (:mod:`pdeinv.nets.corrections`: a U-Net on a regular grid,
``g = E U(Ê b(y))``, or a dense MLP on ``(y, b(y))`` for small 1-D meshes) whose last layer starts at
zero, so ``f = b`` until the correction is fitted.
:meth:`Refined.fit_prior` fits ``g`` (``b`` frozen) after the rule, on prior draws ``(x, y)`` — the
scene's sampler, or the rows of the user's file that carry ``x`` (never the test rows):

    min_g  mean_i ‖b_λ(y_i) + g(y_i, b(y_i)) − x_i‖²,

Adam, early-stopped on held-out draws (the first check is ``b_λ`` itself, ``g = 0``); the correction is
kept only if it lowers the held-out relative L²(Ω) error (otherwise ``g`` stays zero, ``λ = 0`` and
``f = b``): never worse than the base on draws from the prior. Where the operator has a spectral basis, a
kept correction is followed by the data-consistency layer ``D`` (:mod:`pdeinv.nets.consistency`), fitted on
the held-out draws, so that ``f(y) = D(y, b_λ(y) + g(y, b(y)), b(y))`` keeps the base's estimate in the
modes the data resolve at the noise level and changes only the others: the prior decides only what the
data do not, and the rule decides what they do (where it fits the observations, ``f`` does too). This is
the post-processing design of learned reconstruction (Jin et al. 2017, FBPConvNet), with the
physics-trained ``b`` in place of a fixed classical inverse, and
the null-space idea of Schwab, Antholzer & Haltmeier (2019) for what it may change.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from torch import nn

from ..fem.grid import GridMap
from ..util.schedules import Constant, Cosine
from .consistency import DataConsistency
from .corrections import DenseCorrection, GridCorrection, SpanCorrection, SpectralFilter, UNet
from .protocol import Network, declared

__all__ = ["DataConsistency", "DenseCorrection", "GridCorrection", "PriorFit", "PriorFitted", "Refined",
           "SpanCorrection", "SpectralFilter", "UNet"]


@dataclass(frozen=True)
class PriorFit:
    """How :meth:`Refined.fit_prior` fits the correction, in counts: Adam at ``lr`` (``None``: the
    correction's own ``fit_lr``), ``batch`` draws per
    step, at most ``steps`` steps (``None``: :data:`EPOCHS` passes over the training draws, at most
    :data:`MAX_STEPS`), the held-out error checked once per pass over the training draws on ``held_out``
    of them; after ``patience`` checks without a relative improvement of ``min_gain`` over the best so far
    it restarts from that best at a quarter of the lr, at most ``decays`` times, then stops; the best is
    what is kept. ``schedule`` multiplies the lr at step ``t`` of the fit's ``T``
    (:mod:`pdeinv.util.schedules`: constant by default; a fit the count ends before its plateau gains
    from the larger steps a decay would take away). The same settings and seed give
    the same network on any machine and any load."""

    steps: int | None = None
    lr: float | None = None  # None: the correction's own (``fit_lr``: U-Net 4e-3, dense 1e-3)
    batch: int | None = None  # None: the correction's own (``fit_batch``: U-Net 32, dense 128)
    held_out: float = 0.125
    patience: int = 5
    min_gain: float = 0.005
    decays: int = 2
    seed: int = 0
    schedule: Constant | Cosine = Constant()

    def __post_init__(self):
        from .._checks import count, seed

        if not callable(self.schedule):
            raise TypeError(f"PriorFit(schedule={self.schedule!r}) is not allowed; expected a schedule of "
                            "pdeinv.util.schedules (Cosine(), Constant()): a callable (step, steps) -> "
                            "factor")
        if self.steps is not None:  # 0: the blend and the data-consistency layer only
            count(self.steps, "PriorFit(steps)", minimum=0)
        seed(self.seed, "PriorFit(seed)")
        count(self.patience, "PriorFit(patience)")
        count(self.decays, "PriorFit(decays)", minimum=0)
        if self.batch is not None:
            count(self.batch, "PriorFit(batch)")
        lr = self.lr
        if lr is not None and (isinstance(lr, bool) or not isinstance(lr, float | int)
                               or not (math.isfinite(lr) and lr > 0)):
            raise ValueError(f"PriorFit(lr={lr!r}) is not allowed; expected a finite number > 0, or None "
                             "(the correction's own)")
        if not 0 < self.held_out < 1:
            raise ValueError(f"PriorFit(held_out={self.held_out!r}) is not allowed; expected a fraction in "
                             "(0, 1)")
        if isinstance(self.min_gain, bool) or not isinstance(self.min_gain, float | int) \
                or not 0 <= self.min_gain < 1:
            raise ValueError(f"PriorFit(min_gain={self.min_gain!r}) is not allowed; expected a fraction in "
                             "[0, 1) (the relative improvement a check must make)")

    def applies(self, model) -> bool:
        """Whether ``model`` has a part fitted on prior draws (:class:`PriorFitted`)."""
        return isinstance(model, PriorFitted)

    def step_count(self, n_train: int, batch: int) -> int:
        """The steps of a fit on ``n_train`` training draws in batches of ``batch``: ``steps``, or
        :data:`EPOCHS` passes, at most :data:`MAX_STEPS`."""
        if self.steps is not None:
            return self.steps
        return int(min(MAX_STEPS, EPOCHS * math.ceil(max(n_train, 1) / batch)))

    def fit(self, model, x, y, relative_error, log=None) -> dict:
        """``model.fit_prior`` with these settings (:meth:`Refined.fit_prior`)."""
        return model.fit_prior(x, y, relative_error, self, log)


#: passes over the training draws of a default prior fit (the SIP paper's boxes at 64×64 were still
#: improving after ~55 passes of 3 584 draws; the plateau rule ends earlier fits)
EPOCHS = 60

#: the most steps of a fit without a step count (the prior stage counts its own,
#: :func:`pdeinv.training.plan.step_count`)
MAX_STEPS = 8192

#: the steps after which a logged fit says how long it will take (the first pass over the draws can last
#: minutes; a check of the held-out error only comes after it)
PACE_STEPS = 20


#: :class:`_Feed` stores the base's estimates and the correction's inputs for all draws up to this many
#: entries per array (2²⁶: 268 MB in float32), and computes them per batch beyond: heat_2d at 65 025
#: unknowns, 1 537 draws, stored 1.2 GB (plus the float32 copy of x), against one batch's base and filter
#: products (~0.1 s beside a U-Net step of seconds)
STORED_ENTRIES = 2**26

#: training rows the correction's input scales are set on when the feed is computed per batch
PREPARE_ROWS = 512


class _Feed:
    """``feed(rows) -> (b_λ(y_rows), inputs_rows)`` for :meth:`Refined.fit_prior`, ``b_λ = b + λ (x_T − b)``
    with ``λ = mix`` (0 until :meth:`Refined.fit_prior` sets it from :meth:`estimates`): computed once for
    all draws (:meth:`store`) where they fit in :data:`STORED_ENTRIES`, else per call."""

    def __init__(self, base, correction, y):
        self.base, self.g, self.y = base, correction, y
        self.dtype = next(base.parameters()).dtype
        with torch.no_grad():
            width = self.base(torch.as_tensor(y[:1], dtype=self.dtype)).shape[1]
        self.stored = len(y) * max(width, np.shape(y)[1]) <= STORED_ENTRIES
        self._xb = self._t = self._inputs = None
        self.mix = 0.0

    def _filter(self, yb):
        """``x_T(y)`` (float32), or ``None`` without a physics filter."""
        if self.g.physics is None:
            return None
        with torch.no_grad():
            return self.g.physics(yb).float()

    def base_rows(self, rows) -> tuple[torch.Tensor, torch.Tensor]:
        """``(y_rows, b(y_rows))`` in chunks of 512 rows (float32 estimates)."""
        rows = np.asarray(rows)
        with torch.no_grad():
            ys = [torch.as_tensor(self.y[rows[i:i + 512]], dtype=self.dtype)
                  for i in range(0, len(rows), 512)]
            return torch.cat(ys), torch.cat([self.base(yb).float() for yb in ys])

    def store(self) -> _Feed:
        yb, self._xb = self.base_rows(np.arange(len(self.y)))
        chunks = [slice(i, i + 512) for i in range(0, len(yb), 512)]
        ts = [self._filter(yb[c]) for c in chunks]
        self._t = None if self.g.physics is None else torch.cat(ts)
        with torch.no_grad():
            self._inputs = torch.cat([self.g.inputs(yb[c], self._xb[c], t) for c, t in zip(chunks, ts)])
        return self

    def estimates(self, rows) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``(b(y_rows), x_T(y_rows))`` (float32; ``x_T`` ``None`` without a physics filter)."""
        if self._xb is not None:
            return self._xb[rows], None if self._t is None else self._t[rows]
        yb, xb = self.base_rows(rows)
        return xb, self._filter(yb)

    def __call__(self, rows) -> tuple[torch.Tensor, torch.Tensor]:
        if self._xb is not None:
            xb, t, inputs = self._xb[rows], None if self._t is None else self._t[rows], self._inputs[rows]
        else:
            yb, xb = self.base_rows(rows)
            t = self._filter(yb)
            with torch.no_grad():
                inputs = self.g.inputs(yb, xb, t)
        return (xb if t is None or self.mix == 0.0 else xb + self.mix * (t - xb)), inputs

    def chunks(self, rows, size: int = 64):
        """``feed`` over ``rows`` in chunks (the held-out evaluation)."""
        for i in range(0, len(rows), size):
            yield self(rows[i:i + size])


class _Best:
    """The best correction so far over :meth:`Refined.fit_prior`'s held-out checks, with its plateau rule:
    after ``patience`` checks without a relative gain of ``min_gain``, restart from the best at a quarter of
    the lr, at most ``decays`` times, then stop (:meth:`checked` returns True)."""

    def __init__(self, g, opt, settings: PriorFit, before: float, lr: float):
        self.g, self.opt, self.settings = g, opt, settings
        self.before = self.best = before
        self.lr = lr  # before the schedule's factor; a quarter of it after each restart
        self.state, self.bad, self.decays, self.step, self.stopped = None, 0, 0, 0, False
        self.t0, self.mark = time.perf_counter(), 0  # the log's estimate of what is left; its next line

    def pace(self, step: int, steps: int, log) -> None:
        """One line with the fit's estimated time at the pace of its first ``step`` steps (a print:
        nothing is decided by it)."""
        rate = (time.perf_counter() - self.t0) / step
        log(f"prior fit step {step}/{steps}: {rate:.2g} s a step, at most ~{rate * (steps - step):.0f} s "
            "left at this pace")

    def checked(self, err: float, step: int, log=None, steps: int | None = None) -> bool:
        self.step = step
        if log is not None and (not steps or step >= self.mark):  # about ten lines a fit
            self.mark = step + (steps or 0) // 10
            of = f"/{steps}" if steps else ""
            rate = (time.perf_counter() - self.t0) / max(step, 1)
            left = rate * (steps - step) if steps and 0 < step < steps else 0
            log(f"prior fit step {step}{of}: held-out x-error {err:.4g} (base {self.before:.4g})"
                + (f", at most ~{left:.0f} s left" if left >= 1 else ""))
        s = self.settings
        if math.isfinite(err) and err < self.best * (1 - s.min_gain):
            self.best, self.bad = err, 0
            self.state = {k: v.clone() for k, v in self.g.state_dict().items()}
            return False
        self.bad += 1
        if self.bad < s.patience:
            return False
        if self.state is None or self.decays == s.decays:  # a plateau: stop
            self.stopped = True
            return True
        self.decays, self.bad = self.decays + 1, 0  # from the best so far at a quarter of the lr
        self.g.load_state_dict(self.state)
        self.lr /= 4
        return False

    def set_lr(self, step: int, steps: int) -> None:
        """The lr of step ``step`` of ``steps``: the restarts' lr times the schedule's factor."""
        for group in self.opt.param_groups:
            group["lr"] = self.lr * self.settings.schedule(step, steps)


def _adam(params: list, lr: float) -> torch.optim.Adam:
    """Adam over ``params`` with torch's fused kernel where this torch has one for their device (CPU since
    torch 2.4): the same update in one pass over the parameters, not a dozen (a dense correction's step at
    961 unknowns 34 → 27 ms on one thread; the trained weights agree to ~1e-5 after 200 steps)."""
    try:
        return torch.optim.Adam(params, lr, fused=True)
    except (RuntimeError, TypeError, ValueError):  # an older torch, or a device without the kernel
        return torch.optim.Adam(params, lr)


def _blend(feed: _Feed, x, rows) -> float:
    """``λ = Σ⟨x − b, x_T − b⟩ / Σ‖x_T − b‖²`` over ``rows`` (float64 sums): the least-squares blend of the
    base and the physics filter (0 without a filter, or where the two agree)."""
    num = den = 0.0
    for i in range(0, len(rows), 512):
        r = rows[i:i + 512]
        xb, t = feed.estimates(r)
        if t is None:
            return 0.0
        d = (t - xb).double()
        num += float(((torch.as_tensor(x[r]) - xb.double()) * d).sum())
        den += float((d * d).sum())
    lam = num / den if den > 0 else 0.0
    return lam if math.isfinite(lam) else 0.0


@runtime_checkable
class PriorFitted(Protocol):
    """A network with a part fitted on prior draws after the rule (:meth:`Refined.fit_prior`)."""

    def fit_prior(self, x, y, relative_error, settings: PriorFit = ..., log=None) -> dict: ...


class Refined(Network):
    """``f(y) = b(y) + g(y, b(y))`` (module docstring). ``correction``: a strategy of
    :mod:`pdeinv.nets.corrections`; without it, the U-Net on ``grid`` (``channels``, ``dim``, ``physics``:
    :class:`GridCorrection`'s). Until :meth:`fit_prior` keeps a correction, ``f = b`` exactly and the base's
    declared structure (linear in its parameters, decoder, Gauss–Newton diagonal) is the network's: the
    rules train ``b`` as they would alone."""

    def __init__(self, base: nn.Module, grid: GridMap | None = None, channels: int = 16,
                 dim: int | None = None, physics: SpectralFilter | None = None,
                 correction: nn.Module | None = None, consistency: DataConsistency | None = None):
        super().__init__()
        if (correction is None) == (grid is None):
            raise ValueError("Refined takes a grid (the U-Net correction) or a correction, exactly one")
        self.base = base
        self.correction = (GridCorrection(grid, channels, dim, physics) if correction is None
                           else correction).to(torch.float32)
        self.correction.requires_grad_(False)  # trained by fit_prior only
        self.consistency = consistency
        self.register_buffer("active", torch.zeros((), dtype=torch.bool))
        self.register_buffer("mix", torch.zeros(()))  # λ of b_λ = b + λ (x_T − b) (module docstring)
        self.prior_info: dict = {}

    @property
    def correction_kind(self) -> str:
        """``'dense'``, ``'span'`` or ``'grid'`` (:func:`pdeinv.nets.defaults.refined`'s ``correction``)."""
        if isinstance(self.correction, SpanCorrection):
            return "span"
        return "dense" if isinstance(self.correction, DenseCorrection) else "grid"

    # --- the base's declared structure, valid while the correction is off -----------------------
    def fold(self) -> bool:
        return declared(self.base).fold()

    def fit_observations(self, y, noise=None, **settings):
        declared(self.base).fit_observations(y, noise, **settings)
        return self

    def _base(self):
        """The base's declarations while the correction is off; nothing once it is on."""
        return declared(None if bool(self.active) else self.base)

    def linear_in_parameters(self):
        return self._base().linear_in_parameters()

    def gauss_newton_diagonal(self, y):
        return self._base().gauss_newton_diagonal(y)

    def gauss_newton_max(self, y):
        return self._base().gauss_newton_max(y)

    def coefficients(self, y):
        return self._base().coefficients(y)

    @property
    def decoder(self):
        return self._base().decoder

    @property
    def decoder_info(self):
        return declared(self.base).decoder_info

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        xb = self.base(y)
        if not bool(self.active):
            return xb
        x = self.corrected(y, xb)
        return x if self.consistency is None else self.consistency(y, x, xb)

    def corrected(self, y: torch.Tensor, xb: torch.Tensor) -> torch.Tensor:
        """``b_λ(y) + g(y, b(y))`` given ``xb = b(y)``: the estimate before the data-consistency layer."""
        physics = self.correction.physics  # a correction strategy's filter x_T (None: none)
        with torch.no_grad():
            t = None if physics is None else physics(y)
        start = xb
        if t is not None and float(self.mix) != 0.0:  # b_λ = b + λ (x_T − b)
            start = xb + self.mix.to(xb.dtype) * (t.to(xb.dtype) - xb)
        return start + self.correction(self.correction.inputs(y, xb, t)).to(xb.dtype)

    def _apply(self, fn, recurse=True):
        """``.to(dtype)`` moves the base; the correction stays float32 (a network's arithmetic: its output
        corrects a float64 estimate by amounts far above float32 rounding)."""
        super()._apply(fn, recurse)
        self.correction.float()
        return self

    def _fit_inputs(self, y, tr) -> _Feed:
        """What the correction is fitted on, row by row (:class:`_Feed`): the frozen base's estimates of
        ``y`` (float32) and the correction's inputs, its scales set on the training rows ``tr``
        (:meth:`~pdeinv.nets.corrections.DenseCorrection.prepare`; from at most :data:`PREPARE_ROWS` of
        them where the feed is computed per batch)."""
        feed = _Feed(self.base, self.correction, y)
        yb, xb = feed.base_rows(tr if feed.stored else tr[:PREPARE_ROWS])
        self.correction.prepare(yb, xb)
        return feed.store() if feed.stored else feed

    @torch.no_grad()
    def _consistent(self, y, x_c, x, dtype) -> torch.Tensor:
        """The data-consistency layer fitted on held-out rows (``y``, corrected estimates ``x_c``, truths
        ``x``), and its estimate of those rows."""
        self.consistency.fit(y, x_c, x)
        base = self.base(torch.as_tensor(y, dtype=dtype))
        return self.consistency(torch.as_tensor(y, dtype=torch.float64), x_c, base)

    def fit_prior(self, x, y, relative_error, settings: PriorFit = PriorFit(), log=None) -> dict:
        """Fit ``g`` on prior draws ``x`` ``(n, N)``, ``y`` ``(n, m)`` (numpy) with the base frozen, then the
        data-consistency layer's weights on the held-out draws (:mod:`pdeinv.nets.consistency`);
        ``relative_error(xhat, x)`` is the problem's per-sample relative L²(Ω) error (numpy). Returns
        what was done (``kept``, held-out errors before and after, draws, steps)."""
        x, n = np.asarray(x, dtype=float), len(x)
        gen, val, tr = _split(n, settings)
        g, feed = self.correction, self._fit_inputs(y, tr)
        size = min(settings.batch or g.fit_batch, max(len(tr), 1))
        every = max(1, math.ceil(len(tr) / size))  # once per pass over the training draws
        steps = settings.step_count(len(tr), size)

        def held_out(correct: bool = True) -> torch.Tensor:
            with torch.no_grad():
                return torch.cat([xb + g(inp) if correct else xb for xb, inp in feed.chunks(val)]).double()

        def error(xhat) -> float:
            return float(np.mean(relative_error(xhat.numpy(), x[val])))

        before = error(held_out(correct=False))
        # the loss in units of the draws' mean square: Adam's steps (its ε is absolute) the same in any units
        unit = (float(np.mean(x[tr] ** 2)) if len(tr) else 0.0) or 1.0
        lr = settings.lr or g.fit_lr
        opt = _adam(list(g.parameters()), lr)
        track, step = _Best(g, opt, settings, before, lr), 0
        feed.mix = _blend(feed, x, tr if feed.stored else tr[:PREPARE_ROWS])
        if feed.mix != 0.0:
            track.checked(error(held_out()), 0, log)  # b_λ with g = 0: kept if better than b alone
        g.requires_grad_(True)
        track.t0 = time.perf_counter()  # the pace of the steps, without the checks before them
        try:
            while step < steps and len(tr):
                rows = torch.as_tensor(tr[torch.randint(len(tr), (size,), generator=gen).numpy()])
                xb, inputs = feed(rows)
                loss = ((xb + g(inputs) - torch.as_tensor(x[rows], dtype=torch.float32)) ** 2).mean() / unit
                opt.zero_grad(set_to_none=True)
                loss.backward()
                track.set_lr(step, steps)
                opt.step()
                step += 1
                if step == PACE_STEPS and log is not None and steps >= 2 * PACE_STEPS:
                    track.pace(step, steps, log)
                if (step % every == 0 or step == steps) and track.checked(error(held_out()), step, log,
                                                                          steps):
                    break
        finally:
            g.requires_grad_(False)
        if kept := track.state is not None:
            g.load_state_dict(track.state)
        self.active.fill_(kept)
        self.mix.fill_(feed.mix if kept else 0.0)
        after = track.best
        if kept and self.consistency is not None:  # the observations get back what the correction took
            after = error(self._consistent(y[val], held_out(), x[val], feed.dtype))
        self.prior_info = {"kept": kept, "draws": n, "held_out": len(val), "error_before": before,
                           "mix": float(self.mix), "error_corrected": track.best, "error_after": after,
                           "consistency": kept and self.consistency is not None, "steps": step,
                           "max_steps": steps}
        return self.prior_info


def _split(n: int, settings: PriorFit):
    """The seeded generator of the fit and its held-out / training rows: a ``settings.held_out`` share of
    the ``n`` draws (at least one) held out."""
    gen = torch.Generator().manual_seed(settings.seed)
    perm = torch.randperm(n, generator=gen).numpy()
    n_val = max(1, int(round(settings.held_out * n)))
    return gen, perm[:n_val], perm[n_val:]
