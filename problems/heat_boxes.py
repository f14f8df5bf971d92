"""The SIP paper's heat experiment (Holl, Koltun, Thuerey 2022) on finite elements: recover u(0),
a sum of 4–10 axis-aligned boxes, from u(T).

Defaults: the unit square, 64×64×2 P1 triangles (63² = 3 969 unknowns), κT = 8/n² = 8/64² (the
paper's κT = 8 in units of its 64 cells; ``kappa`` unset keeps 8 cells² at any ``n``), the paper's
prior (``prior='boxes'``, :func:`pdeinv.problem.sampling.boxes`: 4–10 boxes, half-sides up to 10 cells,
strengths U(0, 1), centres in the central 80 %), noise-free.
A mode sin(jπx)sin(kπy) keeps an amplification ≈ e^{-κTπ²(j²+k²)}: 1e-3 at j² + k² ≈ 360, float64
rounding (1e-16) at j² + k² ≈ 1 900; the boxes' jumps put energy far beyond both, which only a prior
that knows what a box is can restore.

What differs from the paper: u = 0 on the boundary (the paper is periodic: boxes never touch the
boundary there, here their values on it are dropped); 100 backward-Euler steps (the paper's kernel
is the exact Gaussian, e^{-κTk²} per Fourier mode; backward Euler damps the high modes less,
(1 + κTλ/100)^{-100}); the indicator is sampled at the nodes (no anti-aliasing); the mesh is the
unit square, not 64 unit cells (lengths and κ scaled accordingly). ``n=16`` is the CI-sized
variant (225 unknowns).
"""

from pdeinv import mesh, scenes
from pdeinv import settings as s


def _kappa(value, name):
    return None if value is None else s.positive(value, name)


SETTINGS = {**scenes.HEAT, "n": (64, s.positive_int), "kappa": (None, _kappa),
            "prior": ("boxes", scenes.HEAT["prior"][1]), "mesh": (None, s.optional_path)}


def make(**overrides):
    cfg = s.resolve(SETTINGS, overrides, "heat_boxes")
    if cfg["kappa"] is None:  # κT = 8 cells²: the same smoothing relative to the mesh at every n
        cfg["kappa"] = 8 / (cfg["n"] ** 2 * cfg["T"])
    m = mesh.load(cfg["mesh"], dim=2) if cfg["mesh"] else mesh.unit_square(cfg["n"])
    return scenes.heat("heat_boxes", m, cfg)
