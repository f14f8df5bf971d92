"""A user's own observations: arrays, tensors, torch Datasets and ``.npz`` files, checked once.

**File format** (``pdeinv train --data``, ``pdeinv predict --data``): an ``.npz`` with
array ``y`` ``(B, m)``, the observations (required), and ``x`` ``(B, N)``, the true
fields (optional; used only to report errors, never to train or to fit the whitening).

**Held-out rows** (:func:`split`; one rule for ``Trainer(data=...)`` and the CLI): the
rows keep their order. The **last** ``n_test`` rows are the test set (errors are
reported on them); when a stopping rule is on, the ``n_val`` rows before them are
its held-out observations; the first ``B − n_test − n_val`` rows train. Nothing is
shuffled, so put the rows in random order if the file is sorted (by time, by
sample…) and the test rows should be representative.

**Checked against our physics** (:func:`model_mismatch`): when ``x`` is given, the mean over the
rows of ``‖P x − y‖ / ‖y‖`` (Euclidean on the observation coefficients) says how far the file's
simulator (or instrument) is from ours; with noise of relative level ``δ``
(:func:`pdeinv.problem.sampling.add_noise`: ``y + δ·rms(y)·ε``) it is about ``δ`` from the noise alone.
The trainer records it (``metrics["data"]["model_mismatch"]``) and warns when it exceeds what the
run's noise level explains (:data:`MISMATCH_SLACK`); beyond :data:`MISMATCH_FACTOR` times that level
(:func:`beyond_noise`) the CLI refuses the file (exit 3, ``--accept-bad`` keeps it).

Refused with a ``ValueError`` naming the file and what was expected: not an npz,
an empty file, a missing ``y``, a wrong shape (``y`` must have the problem's ``m``
columns, ``x`` its ``N`` and as many rows as ``y``), NaN or Inf, a non-numeric array,
too few rows for the held-out sets and one batch.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def as_observations(data, m: int, name: str = "data") -> np.ndarray:
    """``data`` (numpy array, torch tensor or torch ``Dataset``) as a float64 ``(B, m)`` array.

    A Dataset item is one observation ``(m,)``, a tuple ``(y,)`` (``TensorDataset(y)``) or a pair
    ``(y, x)`` (``TensorDataset(y, x)``; its ``x``: :func:`paired_fields`).
    """
    from torch.utils.data import Dataset

    if isinstance(data, Dataset):
        items = [item[0] for item in _items(data, name)]
        data = np.stack([_numpy(item, name) for item in items]) if items else np.zeros((0, m))
    return _rows(_numpy(data, name), m, name)


def paired_fields(data, name: str = "data"):
    """The fields ``x`` of a Dataset of ``(y, x)`` pairs as an array (None for anything else)."""
    from torch.utils.data import Dataset

    items = _items(data, name) if isinstance(data, Dataset) else []
    if not items or len(items[0]) < 2:
        return None
    return np.stack([_numpy(item[1], name) for item in items])


def _items(data, name: str) -> list[tuple]:
    """A Dataset's items, each as ``(y,)`` or ``(y, x)``, all of one kind."""
    items = [_item(_read(data, i, name), name) for i in range(len(data))]
    if len({len(item) for item in items}) > 1:
        raise ValueError(f"{name}: a Dataset mixes items (y,) and pairs (y, x); expected one kind")
    return items


def _read(data, i: int, name: str):
    """Item ``i`` of a user's Dataset; its failure a ``ValueError`` naming the item (a ``__len__`` larger
    than what ``__getitem__`` serves, a file that went away)."""
    try:
        return data[i]
    except Exception as err:  # noqa: BLE001  a user's __getitem__
        raise ValueError(f"{name}: item {i} of the Dataset (len {len(data)}) raised {type(err).__name__}: "
                         f"{str(err)[:120]}; expected every item 0 … len - 1 to be readable") from err


def _item(item, name: str) -> tuple:
    """A Dataset item as ``(y,)`` or ``(y, x)``; a list of numbers is one observation."""
    whole = isinstance(item, (tuple, list)) and all(np.ndim(e) == 0 for e in item)
    item = tuple(item) if isinstance(item, (tuple, list)) and not whole else (item,)
    if not 1 <= len(item) <= 2:
        raise ValueError(f"{name}: a Dataset item has {len(item)} elements; expected one observation y, "
                         "(y,) or a pair (y, x)")
    return item


def _numpy(a, name: str = "data") -> np.ndarray:
    import torch

    if isinstance(a, torch.Tensor) and a.is_meta:
        raise ValueError(f"{name} is a tensor on the 'meta' device (shapes only, no values); expected "
                         "numbers: a numpy array or a tensor on the cpu or a cuda device")
    if isinstance(a, np.ma.MaskedArray) and np.ma.getmaskarray(a).any():  # the mask would be dropped
        raise ValueError(f"{name} is a masked array with {int(np.ma.getmaskarray(a).sum())} masked values; "
                         "expected every value observed: drop those rows or fill them")
    if not isinstance(a, torch.Tensor):
        return np.asarray(a)
    a = a.detach().cpu()
    return (a.float() if a.dtype == torch.bfloat16 else a).numpy()  # numpy has no bfloat16


def _rows(a: np.ndarray, width: int, name: str) -> np.ndarray:
    if a.dtype == object or not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise ValueError(f"{name} has dtype {a.dtype}; expected a real numeric array")
    if a.ndim != 2 or a.shape[1] != width:
        flipped = a.ndim == 2 and a.shape[0] == width
        hint = " (it looks transposed: rows are samples; pass its .T)" if flipped else ""
        raise ValueError(f"{name} has shape {a.shape}; expected (B, {width}) for this problem{hint}")
    if a.shape[0] == 0:
        raise ValueError(f"{name} has no rows; expected (B, {width}) with B >= 1")
    if not np.isfinite(a).all():
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
        raise ValueError(f"{name} holds {int((~np.isfinite(a)).sum())} NaN/Inf values (first at {bad}); "
                         "expected finite values")
    return np.ascontiguousarray(a, dtype=np.float64)


def rounding_level(a) -> float:
    """The relative noise level a floating dtype's rounding puts into data stored in it: its unit
    roundoff ``eps/2`` (float32: 6e-8, float16: 5e-4); 0 for float64 and wider. Information below it is
    gone, and a solve that assumes exact data amplifies it (heat_1d from a float32 file: SIP's x-error
    17.7 against 0.02 with the same data in float64). ``a``: an array or a torch tensor."""
    import torch

    if isinstance(a, torch.Tensor):
        eps = torch.finfo(a.dtype).eps if a.is_floating_point() else 0.0
    else:
        dtype = np.asarray(a).dtype
        eps = float(np.finfo(dtype).eps) if np.issubdtype(dtype, np.floating) else 0.0
    return float(eps / 2) if eps > np.finfo(np.float64).eps else 0.0


#: an estimated relative noise level below this is read as clean data (rounding and the tail of a
#: truncated spectral basis)
NOISE_FLOOR = 1e-6


def undeclared_noise(path, y, problem=None) -> float:
    """The noise a data file carries without declaring it: the larger of its storage rounding
    (:func:`npz_rounding_level`) and the level its observations show outside ``range(P)``
    (:func:`pdeinv.inverse.noise.estimate_noise_outside`, exact under white noise), when ``problem``'s
    operator
    has a spectral basis with enough directions outside it and the level is above :data:`NOISE_FLOOR`.
    Elsewhere (an invertible operator: the wave scenes, or few observations) nothing is estimated: the
    singular-value estimate (:func:`pdeinv.inverse.noise.estimate_noise`) read 2.4e-4 on clean heat_1d files
    of 15 observations, and a level that is wrong either way misleads the Wiener target."""
    from ..inverse.noise import estimate_noise_outside
    from ..physics.backends.compiled import spectral_basis
    from ..physics.capabilities import reversible

    level = npz_rounding_level(path)
    op = None if problem is None else problem.operator
    if op is None or (reversible(op) and op.n_out <= op.n_in):  # it keeps every direction: none outside
        return level
    # no SVD for a reversible map (above)
    basis = spectral_basis(op, None if problem.disc is None else problem.disc.M)
    from ..problem.units import for_checks

    y = y / for_checks(y)
    est = None if basis is None else estimate_noise_outside(y, basis.out[:, basis.g > 1e-12 * basis.g.max()])
    return max(level, est if est is not None and est > NOISE_FLOOR else 0.0)


#: the rows :func:`read_noise` reads (the first ones): the SVD of more costs seconds (65 536 × 1 024 on one
#: thread) and moves the reading little
NOISE_ROWS = 1024


def read_noise(y, operator) -> float:
    """The relative noise level observations ``y`` show (:func:`pdeinv.inverse.noise.estimate_noise` over
    their first :data:`NOISE_ROWS` rows); ``inf`` where they are noise all through (no low-rank signal:
    pure noise, all zeros); 0 where it is not read: fewer than 4 rows or columns, or a nonlinear map,
    which makes its own fine scales (sine_gordon_1d, noise-free, reads 0.135)."""
    from ..inverse.noise import NoSignal, estimate_noise
    from ..physics.nonlinear import is_linear
    from ..problem.units import for_checks

    y = y[:NOISE_ROWS]
    if min(y.shape) < 4 or not is_linear(operator):
        return 0.0
    try:
        return estimate_noise(y / for_checks(y))
    except NoSignal:
        return float("inf")


#: the fewest rows whose noise reading may refuse a file as signal-free (:func:`no_signal`): the reading takes
#: the median singular value as noise, which holds only where most of the rows' directions are noise; valid
#: files of 4–6 rows read "no signal" (wave_2d noise-free, 6 rows: up to 9.6), none of 8 or more on 7 scenes
NO_SIGNAL_ROWS = 16


def no_signal(level: float, rows: int) -> str | None:
    """Why ``rows`` observations whose noise level reads ``level`` (:func:`read_noise`,
    :func:`undeclared_noise`) carry nothing to estimate from — noise of that level accounts for all of them,
    so Morozov's principle accepts the estimate 0 (:func:`pdeinv.inverse.noise.signal_free`) —, in one
    clause; None when they show a signal or are fewer than :data:`NO_SIGNAL_ROWS` (too few to tell). The one
    check of ``classical``, ``train`` and ``predict`` (exit 3)."""
    from ..inverse import Discrepancy
    from ..inverse.noise import signal_free

    if rows < NO_SIGNAL_ROWS or not signal_free(level, Discrepancy(1.0).tau):
        return None
    read = "more than all of ‖y‖" if level == float("inf") else f"{level:.3g}"
    return (f"shows no signal: the noise level read from its observations ({read}) accounts for all of them "
            "(Morozov's principle accepts the estimate 0), so nothing can be estimated from them: pure noise "
            "or all zeros?")


def npz_rounding_level(path) -> float:
    """:func:`rounding_level` of the array ``y`` of a file :func:`read_npz` has accepted."""
    with np.load(path, allow_pickle=False) as f:
        return rounding_level(f["y"])


def read_npz(path, m: int, n: int) -> tuple[np.ndarray, np.ndarray | None]:
    """``(y, x or None)`` from an ``.npz`` file, checked against a problem's ``m`` and ``N = n``."""
    path = Path(path)
    where = f"data file {os.fspath(path)!r}"
    if not path.exists():
        raise FileNotFoundError(f"{where} does not exist")
    if not path.is_file():
        raise ValueError(f"{where} is not a file; expected an .npz with array 'y'")
    if path.stat().st_size == 0:
        raise ValueError(f"{where} is empty; expected an .npz with array 'y' (np.savez(file, y=y))")
    arrays = _arrays(path, ("x", "y"))
    if "y" not in arrays:
        raise ValueError(f"{where} has no array 'y'; expected np.savez(file, y=y[, x=x]) with y (B, {m})")
    y = _rows(arrays["y"], m, f"{where}: y")
    x = arrays.get("x")
    if x is not None:
        x = _rows(x, n, f"{where}: x")
        if len(x) != len(y):
            raise ValueError(f"{where}: x has {len(x)} rows but y has {len(y)}; expected one x per y")
    return y, x


def _first(err: BaseException, n: int) -> str:
    return (str(err).strip().splitlines() or [type(err).__name__])[0][:n]


def _arrays(path, keys) -> dict:
    """The arrays ``keys`` of the ``.npz`` at ``path`` that it holds, each a numpy array of numbers or
    text (checked by the caller), never a pickle: a file that is no ``.npz``, a member that is no
    ``.npy`` (a zip of text) or an object array is a ``ValueError`` in one line naming the file."""
    where = f"data file {os.fspath(path)!r}"
    try:
        f = np.load(path, allow_pickle=False)
    except Exception as err:  # noqa: BLE001  (zip, pickle, header errors differ by content)
        # numpy takes a file with neither magic for a pickle, which allow_pickle=False refuses
        why = "not a zip of .npy arrays" if "pickle" in str(err) else _first(err, 100)
        raise ValueError(f"{where} is not an .npz archive ({why}); expected np.savez(file, y=y[, x=x])") \
            from None
    if not isinstance(f, np.lib.npyio.NpzFile):
        raise ValueError(f"{where} is not an .npz archive (a single .npy array); expected np.savez(file, "
                         "y=y[, x=x])")
    from collections import Counter

    twice = sorted(n for n, k in Counter(f.zip.namelist()).items() if k > 1)
    if twice:  # numpy would read the last one silently
        f.close()
        raise ValueError(f"{where} holds {', '.join(twice)} more than once; expected one member per array "
                         "(np.savez(file, y=y[, x=x]))")
    out = {}
    with f:
        for k in (k for k in f.files if k in keys):
            try:
                value = f[k]
            except Exception as err:  # noqa: BLE001  (an object array, a damaged member)
                why = "an object array (pickled Python objects)" if "Object arrays" in str(err) else \
                    f"a damaged array ({_first(err, 80)})"
                raise ValueError(f"{where}: {k} is {why}; expected an array of numbers") from None
            if not isinstance(value, np.ndarray):
                raise ValueError(f"{where}: {k} is not a numpy array (the archive's {k}.npy is not in .npy "
                                 "format); expected np.savez(file, y=y[, x=x])")
            out[k] = value
    return out


def read_meta(path, points) -> dict:
    """The optional keys of a data file, checked: ``noise`` (one number ≥ 0, the relative level, as
    ``--set noise=``) and ``points`` (the coordinates of the columns of ``x``, ``(dim, N)``, which must
    be the problem's ``points`` to 1e-9 of their largest coordinate: the same unknowns in the same
    order). ``{"noise": δ}`` when the file declares a level; a mismatch is a ``ValueError`` naming it."""
    where = f"data file {os.fspath(path)!r}"
    meta = _arrays(path, ("noise", "points"))
    out = {}
    if "noise" in meta:
        v = meta["noise"]
        if v.size != 1 or not np.issubdtype(v.dtype, np.number) or not np.isfinite(v).all() or float(v) < 0:
            said = f"noise={v.tolist()!r}" if v.size == 1 else f"noise of shape {v.shape} ({v.size} values)"
            raise ValueError(f"{where}: {said} is not allowed; expected one number >= 0 (the relative noise "
                             "level, as --set noise=)")
        from ..problem.settings import FLOAT_MAX, _in_range

        try:
            out["noise"] = _in_range(float(v), "noise", f"{float(v):g}")  # --set noise='s range
        except ValueError:
            raise ValueError(f"{where}: noise={float(v):g} is out of range; expected 0 or a level between "
                             f"{1 / FLOAT_MAX:g} and {FLOAT_MAX:g}") from None
    if "points" in meta:
        got, ref = meta["points"], np.asarray(points, dtype=float)
        if got.shape != ref.shape or not np.issubdtype(got.dtype, np.number):
            raise ValueError(f"{where}: points has shape {got.shape}; expected {ref.shape} (the coordinates "
                             "of the problem's unknowns, problem.points: one column per column of x)")
        diff = np.abs(got.astype(float) - ref).max(0)
        worst = int(np.argmax(diff))
        if not diff[worst] <= 1e-9 * max(float(np.abs(ref).max()), np.finfo(float).tiny):
            a, b = got[:, worst].tolist(), ref[:, worst].tolist()
            raise ValueError(f"{where}: points differ from the problem's by up to {diff[worst]:.3g} "
                             f"(column {worst}: {a} against {b}); the columns must be the problem's unknowns "
                             "in its order (docs/own-data.md: data on another grid is interpolated first)")
    return out


#: the mismatch a run explains: ``MISMATCH_SLACK[0]·δ`` with noise level ``δ`` (the noise alone gives
#: ≈ δ; 1.1 leaves room for the spread of a finite file), else ``MISMATCH_SLACK[1]`` (a float32 file of
#: our own simulator is off by ~6e-8)
MISMATCH_SLACK = (1.1, 1e-6)


def model_mismatch(op, x: np.ndarray, y: np.ndarray) -> float:
    """Mean over rows of ``‖P x_i − y_i‖ / ‖y_i‖`` (Euclidean): how far data ``(x, y)`` made elsewhere is
    from ``op`` (module docstring); on rows divided by a power of ten where their squares would leave
    float64 (:func:`pdeinv.problem.units.for_checks`: the figure is scale-free)."""
    from ..fem.forms import relative_norms
    from ..problem.units import for_checks

    c = for_checks(y, op)
    x, y = x / c, y / c
    r = np.linalg.norm(np.asarray(op.forward(x)) - y, axis=1)
    return float(np.mean(relative_norms(r, np.linalg.norm(y, axis=1))))  # a zero row of y: on the rows' scale


def zero_rows(y: np.ndarray, x: np.ndarray | None = None) -> str | None:
    """A clause naming the rows of ``y`` that are all zero (with ``x``: whose ``x`` are not, so ``P x`` is
    not zero either: observations missing, not an empty field), or None."""
    zero = ~np.any(y != 0, axis=1)
    if x is not None:
        zero &= np.any(x != 0, axis=1)
    rows = np.flatnonzero(zero)
    if not rows.size:
        return None
    if rows[-1] - rows[0] + 1 == rows.size:
        which = f"row {rows[0]}" if rows.size == 1 else f"rows {rows[0]}–{rows[-1]}"
    else:
        shown = ", ".join(map(str, rows[:5])) + (", …" if rows.size > 5 else "")
        which = f"rows {shown} ({rows.size} in all)"
    return f"{which} of y are all zero" + (" while their x are not" if x is not None else "")


def explained(mismatch: float, noise: float) -> bool:
    """Whether ``mismatch`` is within what noise of relative level ``noise`` explains."""
    return mismatch <= (MISMATCH_SLACK[0] * noise if noise else MISMATCH_SLACK[1])


#: a figure of :func:`against` above ``MISMATCH_FACTOR`` times the noise level (and above ``MISMATCH_FLOOR``)
#: is more than noise: the data come from another physics or other settings (κ, T, the mesh). The one
#: limit (:func:`beyond_noise`) of ``pdeinv classical`` (exit 3), ``train --data`` and ``predict`` (refused,
#: exit 3; ``--accept-bad`` keeps the run)
MISMATCH_FACTOR = 5.0
MISMATCH_FLOOR = 0.05


def mismatch_limit(noise: float) -> float:
    """The largest figure of :func:`against` noise of relative level ``noise`` explains (above
    :func:`explained`'s, which only warns): ``max(MISMATCH_FACTOR·noise, MISMATCH_FLOOR)``."""
    return max(MISMATCH_FACTOR * noise, MISMATCH_FLOOR)


def beyond_noise(what: str, figure: float, noise: float, y=None, x=None) -> str | None:
    """Why observations whose ``what`` (of :func:`against`) is ``figure`` are not of a problem at noise
    level ``noise`` — ``figure`` above :func:`mismatch_limit` (or not a number) —, in one clause; None
    within it. With the file's ``y`` and ``x``: rows of ``y`` all zero whose ``x`` are not (:func:`zero_rows`)
    are named, whatever the mean (``P x`` of a nonzero field is not zero: observations missing)."""
    if y is not None and x is not None and (zero := zero_rows(y, x)) is not None:
        return f"{zero}: observations missing? (P x of a nonzero x is not zero); drop those rows"
    limit = mismatch_limit(noise)
    if figure <= limit:
        return None
    return (f"its {what} is {figure:.3g}, above {limit:.3g}, the most noise of level {noise:g} explains "
            f"({MISMATCH_FACTOR:g}× the level, at least {MISMATCH_FLOOR:g}): the data come from another "
            "physics or other settings (κ, T, the mesh?)")


#: a declared noise level ``δ`` is refused when the file's own ``x`` show a model mismatch below this
#: fraction of what noise of level ``δ`` gives (``δ/√(1+δ²)`` for ``y = P x + δ·rms(P x)·ε``): a mean over
#: rows of norms over all observations, so within a few % of it for real noise of that level
BELOW_FACTOR = 0.1


def below_noise(figure: float, noise: float, by: str = "") -> str | None:
    """Why a model mismatch ``figure`` (:func:`model_mismatch`, the file has ``x``) contradicts a declared
    noise level ``noise``: far less than noise of that level leaves (a ``noise=1e6`` on noise-free data);
    None where it does not. ``by``: who declared it (``"--set noise=0.05"``), else the file itself."""
    expected = noise / np.sqrt(1.0 + noise**2)
    if noise <= 0 or figure >= BELOW_FACTOR * expected:
        return None
    said = f"{by} declares its noise" if by else f"it declares noise={noise:g}"
    return (f"{said}, but its y differ from P x by {figure:.3g} (mean ‖P x − y‖/‖y‖), "
            f"below {BELOW_FACTOR:g}× the {expected:.3g} noise of that level leaves: a wrong noise level?")


def against(problem, y: np.ndarray, x: np.ndarray | None, path=None) -> tuple[str, float]:
    """``(what, figure)``: how far observations from elsewhere are from ``problem``'s physics — with
    ``x``, :func:`model_mismatch`; else the noise level they show outside ``range(P)``
    (:func:`undeclared_noise`, 0 where it cannot be read). Compare it with the level the problem
    assumes (:func:`explained`: a warning) and with its limit (:func:`beyond_noise`: refused)."""
    if x is not None:
        return "model mismatch mean ‖P x − y‖/‖y‖", model_mismatch(problem.operator, x, y)
    return "noise level outside the range of P", undeclared_noise(path, y, problem) if path else 0.0


def split(rows: int, n_test: int, n_val: int = 0, n_cal: int = 0) -> tuple[slice, slice, slice, slice]:
    """``(train, calibration, val, test)`` row slices: the last ``n_test`` rows test, the ``n_val`` before
    them val, the ``n_cal`` before those calibration, the rest train."""
    n_train = rows - n_test - n_val - n_cal
    if n_train < 2:
        raise ValueError(f"the data has {rows} rows; {n_test} test rows"
                         + (f" and {n_val} rows for the stopping rule" if n_val else "")
                         + (f" and {n_cal} calibration rows" if n_cal else "")
                         + " are held out from its end, leaving fewer than 2 to train on "
                         "(lower n_test / --n-test or give more rows)")
    cal = n_train + n_cal
    return slice(0, n_train), slice(n_train, cal), slice(cal, cal + n_val), slice(cal + n_val, rows)


def fingerprint(y: np.ndarray, x: np.ndarray | None = None) -> str:
    """A short hash of the observations and, where the file has them, their fields (they train the prior
    and calibration stages): a checkpoint of other data is not resumed."""
    digest = hashlib.sha256(np.ascontiguousarray(y, dtype=np.float64).tobytes())
    if x is not None:
        digest.update(b"x" + np.ascontiguousarray(x, dtype=np.float64).tobytes())
    return digest.hexdigest()[:16]


@dataclass
class OwnData:
    """``Trainer(data=...)``'s rows after :func:`own_data`: the training rows, the stopping rule's, the
    test rows (with their ``x`` or None), the data's fingerprint, its model mismatch and the row ranges."""

    y: np.ndarray
    y_val: np.ndarray
    y_test: np.ndarray
    x_test: np.ndarray | None
    fingerprint: str
    model_mismatch: float | None
    rows: dict
    x: np.ndarray | None = None  # the training rows' fields, when the file has them (the prior's draws)
    x_cal: np.ndarray | None = None  # the calibration stage's rows (pdeinv.posterior.stage), with x only
    y_cal: np.ndarray | None = None
    units: float = 1.0  # every array above is the data divided by it (pdeinv.problem.units)

    def describe(self) -> dict:
        """``metrics["data"]``."""
        return {"rows": self.rows, "x": self.x_test is not None, "model_mismatch": self.model_mismatch,
                "units": self.units,
                "split": "in order: first rows train, then the calibration rows (a file with x), the "
                         "stopping rule's rows, the last n_test rows test"}


def _no_repeats(y: np.ndarray, warn: bool = True) -> None:
    """Refuse observations that are one row repeated; warn (``warn``) when rows repeat (a row in both the
    training and the test set makes the test errors optimistic). All-zero rows are not counted as
    repeats: every empty field (an empty box) is observed as zero, and such rows are valid data."""
    distinct = len(np.unique(y, axis=0))
    if distinct == 1 and len(y) > 1:
        raise ValueError(f"data: all {len(y)} rows are the same observation; expected distinct samples (a "
                         "network trained on one observation learns nothing about the others)")
    nonzero = y[np.any(y != 0, axis=1)]
    repeats = len(nonzero) - len(np.unique(nonzero, axis=0))
    if repeats and warn:
        warnings.warn(f"data: {repeats} of {len(y)} rows repeat an earlier row; a row both in the "
                      "training and in the test set makes the test errors optimistic: drop the repeats",
                      RuntimeWarning, stacklevel=4)


def own_data(problem, data, data_x, n_test: int, n_val: int = 0, warn: bool = True,
             calibration=None, *, accept_bad: bool = False) -> OwnData:
    """``data`` (``(B, m)`` observations) and ``data_x`` (their fields or None) checked against ``problem``
    and split by :func:`split`; ``warn``: say when the mismatch exceeds the noise, and what the default
    split held out (the writer process of a data-parallel run); ``calibration``: the run's calibration stage
    (:class:`pdeinv.posterior.CalibrationStage`, or None), which takes its rows of a file with ``x``
    (``own_rows``) before the rules and the prior stage see any. A mismatch beyond what the noise explains
    (:func:`beyond_noise`, the limit ``pdeinv train --data`` refuses with exit 3) is a ``ValueError`` unless
    ``accept_bad`` (the CLI's ``--accept-bad``)."""
    paired = paired_fields(data)
    if paired is not None and data_x is not None:
        raise ValueError("data= is a Dataset of (y, x) pairs and data_x= was given too; give the fields once")
    data_x = paired if paired is not None else data_x
    y = as_observations(data, problem.operator.n_out, "data")
    x = None if data_x is None else as_observations(data_x, problem.N, "data_x")
    import torch

    rounding = rounding_level(data) if isinstance(data, (np.ndarray, torch.Tensor)) else 0.0
    if rounding > problem.noise and warn:  # the CLI trains with the level; a built problem keeps its own
        warnings.warn(f"data is stored in {data.dtype}: its rounding is noise of relative level "
                      f"{rounding:.2g}, above the problem's noise={problem.noise:g}, and is fitted as exact "
                      f"data; build the problem with noise={rounding:.2g} or pass float64 rows",
                      RuntimeWarning, stacklevel=3)
    if x is not None and len(x) != len(y):
        raise ValueError(f"data_x has {len(x)} rows but data has {len(y)}; expected one x per y")
    from ..problem.units import units_of

    print_ = fingerprint(y, x)
    units = units_of(y, problem.operator)
    y, x = y / units, None if x is None else x / units
    mismatch = None if x is None else model_mismatch(problem.operator, x, y)
    why = None if x is None or accept_bad else beyond_noise("model mismatch mean ‖P x − y‖/‖y‖", mismatch,
                                                            problem.noise, y, x)
    if why is not None:
        raise ValueError(f"data: {why}; accept_bad=True (the CLI's --accept-bad) trains on it anyway")
    if mismatch is not None and not explained(mismatch, problem.noise) and warn:
        warnings.warn(f"the data's y differ from this problem's P x by {mismatch:.3g} (mean "
                      f"‖P x − y‖/‖y‖ over the file's rows), more than its noise level "
                      f"{problem.noise:g} explains: another simulator, grid or column order? "
                      "(--set noise=… declares noisy data)", RuntimeWarning, stacklevel=3)
    _no_repeats(y, warn)
    n_cal = 0 if x is None or calibration is None else calibration.own_rows(len(y) - n_test - n_val)
    train, cal, val, test = split(len(y), n_test, n_val, n_cal)
    held = len(y) - train.stop
    if train.stop < held and warn:  # say what the default splits took
        stop = f" and {val.stop - val.start} for the stopping rule" if val.stop > val.start else ""
        stop += f" and {n_cal} for the calibration" if n_cal else ""
        warnings.warn(f"the data's {len(y)} rows: the last {test.stop - test.start} are held out as the "
                      f"test set{stop}, only {train.stop} train; hold out fewer with --n-test "
                      "(Trainer(n_test=...))", RuntimeWarning, stacklevel=3)
    rows = {"train": [0, train.stop], **({"calibration": [cal.start, cal.stop]} if n_cal else {}),
            "stop": [val.start, val.stop], "test": [test.start, test.stop]}
    cal_x, cal_y = (x[cal], y[cal]) if n_cal else (None, None)
    return OwnData(y[train], y[val], y[test], None if x is None else x[test], print_, mismatch, rows,
                   None if x is None else x[train], cal_x, cal_y, units)
