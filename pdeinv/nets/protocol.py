"""What a network declares beyond ``x = f(y)``, asked through :func:`declared`, never by attribute name.

:class:`Network` is the base of pdeinv's networks and of any module that declares something; its
defaults declare nothing:

==============================  ==============================================================
``fit_observations(y, noise)``  fits the input transform on training observations (no-op)
``linear_in_parameters()``      ``x = D(W z(y) + b)``: SIP's Newton step, HIG's Kronecker route
                                (:class:`~pdeinv.nets.net.LinearInParameters`; None)
``gauss_newton_diagonal(y)``    diag of ``(1/B) JᵀJ`` per trainable parameter, exactly (None)
``gauss_newton_max(y)``         its largest eigenvalue in closed form (None)
``decoder``                     the fixed output map's rows ``Dᵀ`` (``(k, N)``; None)
``coefficients(y)``             ``c`` with ``f(y) = c Dᵀ``, without forming the fields (None)
``decoder_info``                how the decoder was chosen (``{}``)
``fold()``                      folds a fitted input transform into the weights where that keeps
                                their shapes (the same function, fewer numbers saved; False)
``fold_into(linear)``           an input transform's part of ``fold`` (False)
==============================  ==============================================================

Any other ``torch.nn.Module`` (a user's own network) is seen through :class:`Undeclared`, which
declares nothing: the rules then take their general routes (autograd gradients, power iterations,
Jacobians).
"""

from __future__ import annotations

from types import MappingProxyType

from torch import nn


class _Nothing:
    """The declarations' defaults shared by :class:`Network` and :class:`Undeclared`: nothing."""

    #: how the decoder was chosen (``reduced`` sets it on the instance)
    decoder_info = MappingProxyType({})

    def linear_in_parameters(self):
        return None

    def gauss_newton_diagonal(self, y):
        return None

    def gauss_newton_max(self, y):
        return None

    def coefficients(self, y):
        return None

    def fold(self) -> bool:
        return False

    def fold_into(self, linear) -> bool:
        return False


class Network(_Nothing, nn.Module):
    """A module with declared capabilities (module docstring); subclasses override what they offer."""

    def fit_observations(self, y, noise: float | None = None, **settings) -> Network:
        return self

    @property
    def decoder(self):
        return None


class Undeclared(_Nothing):
    """A plain ``nn.Module`` as a :class:`Network` that declares nothing (module docstring)."""

    decoder = None

    def __init__(self, model: nn.Module):
        self.model = model

    def fit_observations(self, y, noise: float | None = None, **settings) -> nn.Module:
        return self.model


def declared(model: nn.Module | None) -> Network | Undeclared:
    """``model``'s declarations: the model itself if it is a :class:`Network`, else :class:`Undeclared`
    (for ``None`` too: no network, nothing declared)."""
    return model if isinstance(model, Network) else Undeclared(model)
