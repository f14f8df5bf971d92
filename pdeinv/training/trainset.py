"""What a run trains and is tested on: seeded samples or a user's rows, the held-out sets, the targets.

Without own data (:mod:`pdeinv.training.data`) every set is a draw from ``problem.sample`` with its own seed
stream of the run's ``seed`` (:func:`seed_stream`): the training observations from ``TRAIN_DATA``, the
test pairs from ``TEST_DATA``, the stopping rule's observations from ``VAL_DATA`` (their ``x``
discarded), the batch order from ``BATCH_ORDER``; so other code can rebuild exactly the same data. With
own data the rows come from :class:`pdeinv.training.data.OwnData` (its split, in order).

What ``P f(y)`` must match (:func:`fit_target`) is ``y`` itself, a denoised ``y``
(:mod:`pdeinv.methods.targets`),
or ``y`` in float64 when the network computes in a lower precision.
"""

from __future__ import annotations

import warnings

# numpy and torch are imported where used: the CLI's help reads N_TRAIN without them

#: the trainer's seed streams: training data, test data, batch order, held-out observations, prior draws,
#: fresh draws per step (``Trainer(fresh=True)``), the calibration stage's held-out draws
TRAIN_DATA, TEST_DATA, BATCH_ORDER, VAL_DATA, PRIOR_DATA, FRESH_DATA, CALIBRATION_DATA = 1, 2, 3, 4, 5, 6, 7

#: training samples when not given (``Trainer(n_train=)``, ``pdeinv train --n-train``)
N_TRAIN = 1024

#: test rows when not given (``Trainer(n_test=None)``, ``pdeinv train`` without ``--n-test``): 256 draws
#: of the scene, as the posterior's SBC asks for at least 200 rows (its KS test then tells a rank-CDF gap
#: of 0.096 at 5 %); the last 128 rows of a user's file, whose rows also have to train
N_TEST, N_TEST_FILE = 256, 128


def test_count(n_test, own_rows: bool) -> int | object:
    """``n_test``, or when ``None`` the default test rows (:data:`N_TEST`, or :data:`N_TEST_FILE` for a
    user's file, ``own_rows``); any other value is returned for the caller's check."""
    return n_test if n_test is not None else (N_TEST_FILE if own_rows else N_TEST)


def seed_stream(seed: int, stream: int) -> int:
    """Independent integer seed ``stream`` of ``seed`` (``SeedSequence([seed, stream])``).

    The trainer draws its training pairs from ``seed_stream(seed, TRAIN_DATA)``, its
    test pairs from ``seed_stream(seed, TEST_DATA)`` and its batch order from
    ``seed_stream(seed, BATCH_ORDER)``, so other code can rebuild exactly the same data.
    """
    import numpy as np

    return int(np.random.SeedSequence([seed, stream]).generate_state(1)[0])



def _sample(problem, n: int, seed) -> tuple:
    """``problem.sample(n, seed)``, its rows checked finite: a ``sample`` of the user's own that returns
    NaN was named only as "x contains NaN" by the error evaluation, far from its cause."""
    import numpy as np

    x, y = problem.sample(n, seed)
    for name, a in (("x", x), ("y", y)):
        if not np.isfinite(np.asarray(a, dtype=float)).all():
            raise ValueError(f"problem {problem.name!r}: its sample({n}) returned {name} with NaN or Inf; "
                             "expected finite fields and observations (check its sampler and sample)")
    return x, y

def training_rows(problem, own, n_train: int, seed: int):
    """The training observations (numpy): own data's first rows, or ``n_train`` seeded samples."""
    return own.y if own is not None else _sample(problem, n_train, seed_stream(seed, TRAIN_DATA))[1]


def fresh_rows(problem, size: int, seed: int, step: int):
    """Step ``step``'s ``size`` new observations of the scene's prior (``Trainer(fresh=True)``, the SIP
    paper's protocol): sub-stream ``step`` of stream ``FRESH_DATA`` (:func:`seed_stream`), so a resumed or
    repeated run draws the same; their ``x`` is discarded."""
    return _sample(problem, size, seed_stream(seed_stream(seed, FRESH_DATA), step))[1]


def test_rows(problem, own, n_test: int, seed: int) -> tuple:
    """The test set ``(x or None, y)`` (numpy): own data's last rows, or the seeded samples."""
    return (own.x_test, own.y_test) if own is not None else \
        _sample(problem, n_test, seed_stream(seed, TEST_DATA))


def stop_rows(problem, own, n_val: int, seed: int):
    """The stopping rule's held-out observations (their ``x`` is never drawn into the run)."""
    return own.y_val if own is not None else _sample(problem, n_val, seed_stream(seed, VAL_DATA))[1]


def prior_rows(problem, own, n: int, seed: int, stream: int = 0) -> tuple[tuple | None, str]:
    """``((x, y) or None, source)``: draws of the prior for a network part fitted on it
    (:mod:`pdeinv.nets.refine`). Own data: its *training* rows when the file has ``x`` (never the test or
    stopping rows), ``None`` without ``x`` (the prior is then unknown: never the scene's sampler in its
    place); a scene: ``n`` fresh draws of ``problem.sample`` from sub-stream ``stream`` of
    ``PRIOR_DATA``, in chunks of at most :data:`PRIOR_CHUNK` (each its own sub-stream): a count, so the
    same seed gives the same draws on any machine."""
    import numpy as np

    if own is not None:
        if own.x is None:
            return None, "the data file has no x"
        return (own.x, own.y), f"the data file's x ({len(own.x)} training rows)"
    prior = problem.settings.get("prior", "the scene's sampler")
    first = seed_stream(seed, PRIOR_DATA)

    def chunk_seed(i):  # the first chunk of stream 0 is the stream itself
        return first if stream == 0 and i == 0 else seed_stream(seed_stream(first, stream), i)

    sizes = [min(PRIOR_CHUNK, n - i) for i in range(0, n, PRIOR_CHUNK)]
    parts = [_sample(problem, k, chunk_seed(i)) for i, k in enumerate(sizes)]
    x, y = (np.concatenate(a) for a in zip(*parts, strict=True))
    return (x, y), f"{len(x)} draws of the scene's prior ({prior})"


#: prior draws are made in chunks of this many rows (bounded memory of one call to the sampler; the
#: default stage draws at most this many)
PRIOR_CHUNK = 65_536


def training_fields(problem, own, n_train: int, seed: int):
    """The training rows' true fields (numpy) or ``None``: own data's ``x``, or the seeded draws'
    (the same stream as :func:`training_rows`, so the same rows)."""
    if own is not None:
        return own.x
    return _sample(problem, n_train, seed_stream(seed, TRAIN_DATA))[0]


def fit_inputs(problem, rule, target, model, y_np, y_train, fit_scaling: bool, fields=None):
    """What the network sees and must match: ``(goal, info, of)`` of :func:`fit_target`, and with
    ``fit_scaling`` the model's input transform fitted on ``y_np`` at the problem's noise level
    (:func:`pdeinv.nets.fit_preconditioning`; never on ``x``)."""
    from ..nets import fit_preconditioning

    goal, info, of = fit_target(problem, rule, target, y_np, y_train, model, fields)
    if fit_scaling:  # a fitted target is denoised: the input keeps every direction (drop=0), each scaled
        # at most to the noise floor σ² (clean data's rounding-level directions stay small)
        noise = problem.noise or None
        fit_preconditioning(model, y_np, noise, **({"drop": 0} if info else {}))
    return goal, info, of


def fit_target(problem, rule, target, y_np, y_train, model=None, fields=None):
    """``(goal, info, of)``: what ``P f(y)`` must match when it is not ``y_train`` itself (``goal`` None),
    the fitted target's description (None without one), and ``of(y_np)``, the same for other rows (fresh
    draws: ``Trainer(fresh=True)``; a float64 tensor or None).

    ``target(y)`` when the target strategy fits one (:mod:`pdeinv.methods.targets`, whose protocol
    passes it the network and the training rows' fields; ``"auto"`` is the rule's own
    ``default_target()``, else :class:`~pdeinv.methods.targets.SpectralWiener`), else the float64 ``y``
    when the network's dtype is lower (a float32 copy of ``y`` puts rounding 6e-8 into every residual,
    which SIP's local inverse amplifies by up to ``1/(2√α)``). A rule that does not declare
    ``accepts_target`` (:mod:`pdeinv.methods.protocol`) keeps ``y``: refused for an explicit target,
    with a warning for ``"auto"`` on noisy data."""
    import numpy as np
    import torch

    from ..methods.protocol import declared
    from ..methods.targets import SpectralWiener

    rule = declared(rule)  # target: checked by Trainer (arguments.target)
    strategy = ((rule.default_target() or SpectralWiener()) if target == "auto" else target)
    noise = problem.noise or 0.0
    if strategy is None and noise > 0:
        warnings.warn(f"noise={noise:g} and target=None: every rule converges to the least-squares fit "
                      "of the noise and only a stopping rule regularizes (SIP's default inverse on a "
                      "spectral basis gets there in one step); keep target='auto'", RuntimeWarning,
                      stacklevel=5)
    fitted = None
    if strategy is not None:
        fitted = strategy.fit(problem, y_np, noise or None, model=model, fields=fields or (lambda: None))
    if fitted is not None and not rule.accepts_target:
        if target != "auto":
            raise ValueError(f"rule {rule.name!r} cannot use target={target!r}: it does not declare "
                             "accepts_target = True (its update takes no target=)")
        if noise > 0:
            warnings.warn(f"rule {rule.name!r} takes no target= (it does not declare accepts_target = "
                          f"True): it fits the noisy observations themselves (noise={noise:g}), where "
                          "target='auto' fits a denoised target; only a stopping rule regularizes it",
                          RuntimeWarning, stacklevel=5)
        fitted = None
    info = None if fitted is None else fitted.info

    def of(rows):
        if fitted is None and (y_train.dtype == torch.float64 or not rule.accepts_target):
            return None
        goal = np.asarray(rows, dtype=float) if fitted is None else fitted(rows)
        return torch.as_tensor(goal, dtype=torch.float64, device=y_train.device)

    return of(y_np), info, of
