"""HIG's Kronecker route as one of its routes (:data:`.routes.ROUTES`): the exact step without ``J``
for a network linear in its parameters (:mod:`.kron`), and on rows taken before, from what they gave
once (:mod:`.fixed`). It keeps, across steps, the input Gram of the last rows and what the last
repeated rows carry, so the rule builds it once per run (its context)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ...errors import NonFiniteError
from ...physics.bridge import apply
from ..base import Update, prediction, y_loss
from . import fixed as hig_fixed
from . import kron as hig_kron


@dataclass
class Kronecker:
    """The route of a network that declares ``x = D(W z(y) + b)`` (``lin``), ``fac`` the SVD of the
    physics in the decoder's span (:func:`~pdeinv.inverse.decoder.decoded_svd`)."""

    lin: object
    fac: object
    gram: hig_kron.InputGram = field(default_factory=hig_kron.InputGram)
    seen: dict = field(default_factory=dict)
    name = "kronecker"

    def memory(self, b) -> int:
        """0: it forms no Jacobian, so ``max_jacobian_gb`` does not bound it (its features and their
        ``k̃ × k̃`` Gram are the network's size, counted by the memory guard with the network)."""
        return 0

    def describe(self, b) -> str:
        return "Kronecker route (no Jacobian)"

    def step(self, rule, b, op, Q, goal: torch.Tensor, steps: int) -> Update:
        """The exact step; one pass of the feature map gives ``x`` and the features, and rows taken
        before need neither (:meth:`fixed`). Data-parallel (``rule.sum_over``): every rank joins the
        one sum of the moments, NaN where its shard failed, so all ranks take or refuse the same step."""
        lin, fac, gram, y_target = self.lin, self.fac, self.gram, b.y
        key = None if rule.sum_over is not None else gram.key_of(y_target, None if goal is y_target else goal)
        if key is not None and key == gram.seen:  # the same rows again (the full batch): hig_fixed
            return self.fixed(rule, key, y_target, goal)
        gram.seen = key
        x, Z = hig_kron.forward(lin, y_target)
        try:
            with torch.no_grad():
                r = (apply(op, prediction(x)) - goal).double()
        except NonFiniteError:
            if rule.sum_over is None:
                raise
            r = torch.full((len(Z), op.n_out), math.nan, dtype=torch.float64)
        loss, rows = float(y_loss(r, torch.zeros_like(r))), len(Z)
        R = r.cpu().numpy()
        if rule.sum_over is None and rows < Z.shape[1]:
            # new rows, fewer than features (a minibatch): A = Z̃Z̃ᵀ is the smaller Gram; as many rows as
            # features or more: G = Z̃ᵀZ̃, whose eigenpairs are kept should the same rows come again.
            if not math.isfinite(loss):
                return Update(None, {"loss": loss})
            delta, info = hig_kron.direction_rows(fac, Z, R, rule.eta, rule.tau, rule.exponent)
        else:
            G, N = hig_kron.moments(fac, Z, R, gram.kept(key))
            if rule.sum_over is not None:  # the whole batch's moments and mean loss on every rank
                G, N, totals = rule.sum_over([G, N, np.array([loss * rows, rows])])
                loss, rows = float(totals[0] / totals[1]), int(totals[1])
            if not (math.isfinite(loss) and np.isfinite(N).all()):
                return Update(None, {"loss": loss})
            delta, info = hig_kron.direction(fac, G, N, rows, rule.eta, rule.tau, rule.exponent, gram, key)
        return Update(hig_kron.split(lin, delta * rule.unit(info), lin.layer.weight), {**info, "loss": loss})

    def fixed(self, rule, key: tuple, y_target, goal) -> Update:
        """The step on rows taken before, from what they gave once (:mod:`.fixed`): ``seen`` holds the
        :class:`~.fixed.Carried` state of the last such rows."""
        lin, gram, seen = self.lin, self.gram, self.seen
        if seen.get("key") != key:
            _, Z = hig_kron.forward(lin, y_target)
            a, W = gram(gram.kept(key) if gram.kept(key) is not None else Z.T @ Z, key)
            fixed = hig_fixed.FixedRows.of(self.fac, Z, goal.detach().cpu().double().numpy(), a, W,
                                           rule.tau, rule.exponent)
            seen.update(key=key, carried=hig_fixed.Carried(fixed))
        carried, layer = seen["carried"], lin.layer
        weight = layer.weight.detach().clone() if layer.bias is None else \
            torch.cat([layer.weight.detach(), layer.bias.detach()[:, None]], 1)  # a fresh copy it keeps
        info = carried.fixed.info
        delta, loss = carried.step(weight.cpu().numpy(), rule.eta, rule.unit(info))
        if not math.isfinite(loss):
            return Update(None, {"loss": loss})
        if delta is None:  # below the weights' resolution: nothing to apply (hig_fixed)
            return Update((None,) * len(list(layer.parameters())), {**info, "loss": loss})
        return Update(hig_kron.split(lin, delta, layer.weight, contiguous=False), {**info, "loss": loss})
