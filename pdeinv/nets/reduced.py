"""The reduced network (:func:`reduced`): the whitened :class:`~pdeinv.nets.net.Net` on the leading observed
components with a fixed decoder ``Φ``
(:class:`Decoder`, the prior's principal components, :func:`prior_basis`).

Its trained size, ``k_in·k_out + k_out``, does not depend on the ``N`` unknowns (the whitened linear
map's ``N·m`` does), so its step costs what the physics costs; the error floor is the prior's energy
outside the span of ``Φ``. Used above :data:`~pdeinv.nets.defaults.REDUCED_ABOVE` unknowns, with a
``linear`` body; the decoder's scaling: :func:`prior_basis`. Why: on heat_2d at n = 128 its step is ~120x
cheaper than the whitened linear map's (benchmarks/notes/scaling.md).
"""

from __future__ import annotations

import torch
from torch import nn

from .._checks import activation_class, count, flag, float_dtype, matrix, nonnegative, widths
from .._checks import problem as _problem
from .._checks import seed as _seed
from .net import BODIES, DTYPE, Net, check_body
from .protocol import Network
from .whitening import Whitening, check_settings

#: at most this many decoder columns out of :func:`reduced` (``k_out``); fewer when they hold all but
#: :data:`REDUCED_UNCAPTURED` of the prior's energy. 512: heat_3d's decoder error nearly halves from 256
#: columns to 512 and barely moves beyond; the 2-D scenes need ~270.
REDUCED_K = 512


#: the decoder's columns when :data:`REDUCED_K` are all kept and still leave more than
#: :data:`REDUCED_UNCAPTURED` of the prior's energy out (:func:`decoder_basis`: drawn once more, from
#: ``2·REDUCED_K_MAX`` fields). A 3-D prior fills more directions than a 2-D one (heat_3d at 12 167
#: unknowns needs ~1 560 columns); heat_2d needs ~280 and never grows.
REDUCED_K_MAX = 2048


#: the fraction of the prior's energy (``E‖x‖²_M``) the decoder may leave out: an error floor of
#: ``√1e-10 = 1e-5`` relative, far below what any scene's observations resolve
REDUCED_UNCAPTURED = 1e-10

#: with observations carrying relative noise ``σ``, the decoder may leave out ``(NOISY_FLOOR·σ)²`` of the
#: prior's energy (:func:`decoder_uncaptured`): an error floor of ``NOISY_FLOOR·σ``, added in quadrature to
#: an error no linear estimate brings much below ``σ`` on these scenes. 0.05: at 1 % noise it halves
#: wave_3d's decoder columns for under 2 % more x-error.
NOISY_FLOOR = 0.05


def decoder_uncaptured(noise: float | None) -> float:
    """The energy fraction a default decoder may leave out: :data:`REDUCED_UNCAPTURED`, or
    ``(NOISY_FLOOR·noise)²`` where that is larger. Every decoder column costs one forward solve before
    training (``P D``)."""
    return max(REDUCED_UNCAPTURED, (NOISY_FLOOR * float(noise or 0.0)) ** 2)


#: leading whitened components into :func:`reduced` (``k_in``). 1024 rather than 256: with noisy
#: observations the denoised target depends on y's coordinates along the kept modes, which 256 data
#: directions capture only in part; more than 1024 gains nothing, since 1024 training rows span no more.
REDUCED_K_IN = 1024


def _samples(samples) -> None:
    """``samples``: ``None`` (the default draws) or an integer >= 1."""
    if samples is not None:
        count(samples, "samples")


class Decoder(Network):
    """``x = Φ c``: a fixed basis ``Φ`` (``N × k``, a buffer, not trained) times coefficients ``c``.
    ``persistent=False``: the basis is rebuilt from the problem, not saved (:mod:`pdeinv.nets.modal`)."""

    def __init__(self, basis: torch.Tensor, persistent: bool = True):
        super().__init__()
        flag(persistent, "persistent")
        basis = torch.as_tensor(matrix(basis, "basis"))
        self.register_buffer("basis", basis.T.contiguous(), persistent=persistent)  # (k, N)

    def forward(self, c: torch.Tensor) -> torch.Tensor:
        return c @ self.basis

    @property
    def decoder(self) -> torch.Tensor:
        """Its rows ``Φᵀ`` (``(k, N)``): a network ending in this map declares it as its decoder."""
        return self.basis

    def extra_repr(self) -> str:
        k, n = self.basis.shape
        return f"N={n}, k={k}"


class _Draws:
    """Fields of a problem's prior drawn in chunks of ``chunk`` from one seeded stream, and kept:
    ``take(n)`` is the stream's first ``n`` fields whatever was taken before, so that a second, larger
    pass (:func:`decoder_basis`) reuses the first's and draws only the rest."""

    def __init__(self, problem, seed: int, chunk: int):
        import numpy as np

        self.problem, self.rng, self.chunk = problem, np.random.default_rng(seed), chunk
        self.parts, self.have = [], 0

    def take(self, n: int):
        import numpy as np

        while self.have < n:
            self.parts.append(self.problem.draws(min(self.chunk, n - self.have), self.rng))
            self.have += len(self.parts[-1])
        self.parts = [np.vstack(self.parts)] if len(self.parts) > 1 else self.parts
        return self.parts[0][:n]


def _mass(problem):
    return problem.disc.M if problem.disc is not None else None


def _spectrum(X, M):
    """The second moment's nonzero L²(Ω) spectrum of the drawn fields ``X`` (rows), descending, without
    its directions: the eigenvalues of ``(M XᵀX M, M)`` where the ``N`` unknowns are fewer than half the
    ``n`` draws, else those of the Gram ``X M Xᵀ`` (the same nonzero values, a standard problem)."""
    import numpy as np
    import scipy.linalg as sla

    n, N = X.shape
    if 2 * N < n:
        Md = np.eye(N) if M is None else M.toarray()
        XM = X @ Md
        lam = sla.eigh(XM.T @ XM, Md, eigvals_only=True)
    else:
        lam = np.linalg.eigvalsh(X @ (M @ X.T) if M is not None else X @ X.T)
    return lam[::-1]


def _kept(lam, k: int, uncaptured: float) -> tuple[int, float]:
    """``(k', captured)``: the components out of at most ``k`` that hold all but ``uncaptured`` of the
    energy of the spectrum ``lam`` (descending), at most its numerical rank, and the fraction they hold."""
    import numpy as np

    rank = int((lam > lam[0] * 1e-14).sum())
    tail = 1.0 - np.cumsum(lam[:rank]) / lam[lam > 0].sum()  # uncaptured after j + 1 components
    k = min(k, rank, int(np.searchsorted(-tail, -uncaptured)) + 1)
    return k, float(lam[:k].sum() / lam[lam > 0].sum())


def _basis(X, M, k: int, scaled: bool, uncaptured: float):
    """:func:`prior_basis` of the drawn fields ``X``."""
    import numpy as np
    import scipy.linalg as sla

    n, N = X.shape
    if N < n:  # the N × N side: generalized eigenvectors of (M XᵀX M, M), M-orthonormal
        Md = np.eye(N) if M is None else M.toarray()
        XM = X @ Md
        lam, vecs = sla.eigh(XM.T @ XM, Md)
    else:  # the n × n side: X M Xᵀ = U S² Uᵀ, directions Xᵀ U S⁻¹
        lam, vecs = np.linalg.eigh(X @ (M @ X.T) if M is not None else X @ X.T)
    lam, vecs = lam[::-1], vecs[:, ::-1]
    k, captured = _kept(lam, k, uncaptured)
    dirs = vecs[:, :k] if N < n else X.T @ (vecs[:, :k] / np.sqrt(lam[:k]))
    Phi = np.linalg.qr(dirs)[0]
    if scaled:  # column j ∝ the prior's rms amplitude along it, Σ_j ‖Φ_j‖² = N (see prior_basis)
        rms = np.sqrt(((X @ Phi) ** 2).mean(0))
        Phi = Phi * (rms * np.sqrt(N / (rms**2).sum()))
    return Phi, {"captured": captured, "components": k, "samples": n}


def prior_basis(problem, k: int, samples: int | None = None, seed: int = 20_161, chunk: int = 128,
                scaled: bool = True, uncaptured: float = 0.0):
    """``Φ`` (``N × k'``): the span of the ``k' ≤ k`` leading L²(Ω) principal components of fields
    drawn from the problem's prior (``problem.sampler``), with Euclidean-orthonormal columns.

    The M-principal directions maximize the captured ``E‖x‖²_M`` (second moment, not centred, so
    the prior mean is in the span too): the generalized eigenvectors of ``(M C M, M)`` with
    ``C = XᵀX`` of the ``n`` drawn fields ``X`` (rows), computed on whichever side is smaller —
    ``N × N`` when ``N < n``, else from the ``n × n`` Gram ``X M Xᵀ = U S² Uᵀ`` as ``Xᵀ U S⁻¹`` —
    then a QR makes the columns orthogonal in ``ℝᴺ``. ``k' = k`` unless fewer components hold
    all but a fraction ``uncaptured`` of the drawn energy (or the draws have lower rank).
    ``scaled=True`` (default) then scales column ``j`` by the prior's rms
    amplitude ``σ_j`` along it, normalized so that ``Σ_j ‖Φ_j‖² = N`` (the trace of the
    identity, which is the decoder of a network with nodal outputs): an optimizer step that
    moves every coefficient by ``ε`` moves the field by ``ε`` per node in the mean, whatever
    ``N`` (so Adam's learning rates keep their meaning across meshes), and mostly along the
    directions the prior fills. Why: with orthonormal columns Adam's sign-like steps push the
    low-variance, invisible directions as hard as the leading ones (heat_2d: x-error 1.0 against 0.14).
    Returns ``(Φ, info)``; ``info``: the captured fraction, the components kept and the draws.
    Deterministic (``seed``), so a saved network rebuilds the same buffer.
    """
    _problem(problem)
    k, chunk, seed = count(k, "k"), count(chunk, "chunk"), _seed(seed)
    _samples(samples)
    flag(scaled, "scaled")
    nonnegative(uncaptured, "uncaptured")
    X = _Draws(problem, seed, chunk).take(samples or 4 * k)
    return _basis(X, _mass(problem), k, scaled, uncaptured)


def decoder_basis(problem, k: int = REDUCED_K, k_max: int = REDUCED_K_MAX, samples: int | None = None,
                  scaled: bool = True, uncaptured: float = REDUCED_UNCAPTURED, at_most: float | None = None):
    """:func:`prior_basis` with at most ``k`` columns (where ``k < k_max < N``: as many as the first ``4k``
    draws resolve at two per column, up to ``k_max``); where all are kept and they still leave more
    than ``uncaptured`` of the drawn energy out, once more with at most ``k_max`` columns from
    ``samples`` or ``2·k_max`` draws (:data:`REDUCED_K_MAX`; the first draws among them), provided
    ``k_max`` is below the ``N`` unknowns: a decoder is a reduction, and a prior that no fewer than ``N``
    columns hold is left to :func:`~pdeinv.nets.defaults.linear_default`'s check (heat_boxes at 961
    unknowns: the whitened map). The first, small draw decides for the scenes that need few columns
    (heat_2d: ~280), so they pay nothing for the second. Each pass decides from the spectrum alone
    (:func:`_spectrum`); the directions are computed once, for the pass kept. ``at_most``: a decoder that
    leaves more than this fraction out is not built (``(None, info)``: heat_boxes at 64² decides in a
    third of the time of building the decoder it then refused)."""
    _problem(problem)
    k, k_max = count(k, "k"), count(k_max, "k_max")
    _samples(samples)
    flag(scaled, "scaled")
    nonnegative(uncaptured, "uncaptured")
    if at_most is not None:
        nonnegative(at_most, "at_most")
    n, M = problem.operator.n_in, _mass(problem)
    grows = k < k_max < n
    first = samples or 4 * min(k, n)
    # where it may grow, the first draws already serve up to one column per two draws (a 3-D prior at
    # 1 % noise: ~700 columns from its 2 048 draws, no second draw of 4 096 fields and their Gram)
    wide = min(k_max, max(k, first // 2)) if grows else min(k, n)
    draws = _Draws(problem, 20_161, 128)
    X = draws.take(first)
    if not X.any():
        raise ValueError(f"problem {problem.name!r}: its {len(X)} prior draws are all zero fields (does the "
                         "sampler return zeros?): there is nothing to learn the prior from")
    kept, captured = _kept(_spectrum(X, M), wide, uncaptured)
    if grows and kept >= wide and 1 - captured > uncaptured:
        X, wide = draws.take(samples or 2 * k_max), k_max
        kept, captured = _kept(_spectrum(X, M), wide, uncaptured)
    if at_most is not None and 1 - captured > at_most:
        return None, {"captured": captured, "components": kept, "samples": len(X)}
    return _basis(X, M, wide, scaled, uncaptured)


def reduced(k_in: int = REDUCED_K_IN, k_out: int = REDUCED_K, body: str = "linear", hidden=(256, 256),
            activation=nn.Tanh, rel_floor: float | None = None, drop: float | str = "edge",
            samples: int | None = None, dtype: torch.dtype = DTYPE, scaled: bool = True,
            rows_per_component: float | None = None, uncaptured: float = REDUCED_UNCAPTURED,
            k_max: int = REDUCED_K_MAX, at_most: float | None = None):
    """A ``model_factory`` whose *trained* size does not depend on the mesh:

        x = Φ · body(z),   z = D_k U_kᵀ (y − μ)

    ``z``: the ``k_in`` leading whitened PCA components of the observations
    (:class:`~pdeinv.nets.whitening.Whitening` with ``components=k_in``, fitted on the training
    observations); ``body``: a network ``k_in → k_out`` from :data:`BODIES` with a
    zero-initialized last layer; ``Φ``: a *fixed* decoder basis (``N × k_out``,
    :func:`prior_basis`: the leading principal components of the prior's fields, a buffer).
    Parameters: ``k_in·k_out + k_out`` for the linear body (262 400 at the defaults),
    whatever ``N``; buffers ``(m + N)·k`` grow linearly. Everything outside the span of
    ``Φ`` is out of reach: the error floor is the prior's uncaptured part. ``at_most``: where the decoder
    would leave more than this fraction of the prior's energy out, the factory builds nothing and
    returns ``None`` (:func:`decoder_basis`).
    """
    body = check_body(body)
    k_in, k_out, k_max = count(k_in, "k_in"), count(k_out, "k_out"), count(k_max, "k_max")
    hidden, activation, dtype = widths(hidden), activation_class(activation), float_dtype(dtype)
    check_settings(rel_floor, drop, None, rows_per_component)
    _samples(samples)
    flag(scaled, "scaled")
    nonnegative(uncaptured, "uncaptured")
    if at_most is not None:
        nonnegative(at_most, "at_most")

    def factory(problem) -> nn.Module:
        _problem(problem)
        m = problem.operator.n_out
        basis, info = decoder_basis(problem, k_out, k_max, samples, scaled, uncaptured, at_most)
        if basis is None:
            return None
        pre = Whitening(m, rel_floor, drop, components=min(k_in, m), rows_per_component=rows_per_component)
        net = Net(pre, BODIES[body](pre.k, basis.shape[1], tuple(hidden), activation),
                  Decoder(torch.as_tensor(basis, dtype=dtype))).to(dtype)
        net.decoder_info = info
        return net

    return factory
