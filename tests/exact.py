"""Separable exact solutions shared by the physics tests (torchdiffeq ``tests/problems.py`` style).

On the unit square with u = 0 on the boundary, ``u₀ = sin(πx) sin(πy)`` is a
Laplace eigenfunction with λ = 2π²; in 1-D ``sin(πx)`` has λ = π². Hence

    heat:  u(T) = exp(−κ λ T) u₀,          wave (v₀ = 0):  u(T) = cos(c √λ T) u₀.
"""

import numpy as np
from skfem import Functional

import pdeinv


def mode(points):
    return np.prod(np.sin(np.pi * points), axis=0)


def eigenvalue(dim):
    return dim * np.pi**2


def l2_error(disc, x, factor):
    """‖u_h − factor·u₀‖_{L²(Ω)} by quadrature, ``u_h`` from the free coefficients ``x``."""
    full = disc.extend(x)[0]

    @Functional
    def err2(w):
        return (w["uh"] - factor * np.prod(np.sin(np.pi * w.x), axis=0)) ** 2

    return np.sqrt(err2.assemble(disc.basis, uh=disc.basis.interpolate(full)))


def fitted_rate(hs, errs):
    return np.polyfit(np.log(hs), np.log(errs), 1)[0]


def load(name, **kw):
    return pdeinv.load_problem(name, **kw)


def dot_test(op, B=5, seed=0):
    """|⟨Px, r⟩ − ⟨x, Pᵀr⟩| / (‖Px‖‖r‖), summed over a random batch."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((B, op.n_in))
    r = rng.standard_normal((B, op.n_out))
    Px = op.forward(x)
    return abs(np.vdot(Px, r) - np.vdot(x, op.adjoint(r))) / (np.linalg.norm(Px) * np.linalg.norm(r))


def taylor_rates_through_network(problem, hidden: int, samples: int, eps) -> np.ndarray:
    """Rates of the Taylor remainder ``|J(θ+εd) − J(θ) − ε∇J·d|`` over ``eps`` for
    ``J(θ) = ½‖P f(y; θ) − y*‖²``, ``f`` a tanh MLP with one hidden layer (float64, seeded)."""
    import torch

    op = problem.operator
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(op.n_out, hidden), torch.nn.Tanh(),
                              torch.nn.Linear(hidden, op.n_in)).double()
    _, y = problem.sample(samples, seed=0)
    y = torch.from_numpy(y)
    params = dict(net.named_parameters())

    def J(ps):
        return 0.5 * ((pdeinv.apply(op, torch.func.functional_call(net, ps, (y,))) - y) ** 2).sum()

    grads = torch.autograd.grad(J(params), list(params.values()))
    d = {k: torch.randn_like(v) for k, v in params.items()}
    slope = sum((g * d[k]).sum() for g, k in zip(grads, params))
    with torch.no_grad():
        J0 = J(params)
        rem = [abs(J({k: v + e * d[k] for k, v in params.items()}) - J0 - e * slope).item() for e in eps]
    return np.diff(np.log(rem)) / np.diff(np.log(eps))
