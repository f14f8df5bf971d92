"""``pdeinv classical PROBLEM --data F.npz``: the classical solves of a data file, to compare a run with.

Reads ``y`` (and ``x`` if present) like ``pdeinv train --data`` (:func:`pdeinv.training.data.read_npz`) and
reconstructs every row with what needs no training:

* **Tikhonov with Morozov's α** (x-free): the problem's inverse (:func:`pdeinv.inverse.default_inverse`)
  with :class:`~pdeinv.inverse.Discrepancy` at the noise level — the problem's (``--set noise=``, 0
  included), else the file's, else read from the file: with its ``x`` off the model mismatch
  (:func:`_from_mismatch`), without off ``y``'s singular values (:func:`pdeinv.inverse.noise.estimate_noise`;
  a rounding-level estimate is 0). A noise-free file gets the noise-free α instead (``tikhonov_noise_free``,
  :data:`pdeinv.inverse.NOISE_FREE_REL_ALPHA` of the largest ``g²``);
* **the y-only Wiener target** (x-free, noisy files, where the operator has a spectral basis): what
  ``pdeinv train`` fits the physics to (:mod:`pdeinv.methods.targets`), solved in closed form;
* **the prior Wiener estimate** (x-free): the same filter in the basis of ``P D``, ``D`` the prior's
  principal components (:func:`pdeinv.training.references.prior_wiener`): what the default network converges
  to where the operator is not reversible; it assumes the problem's prior describes the data;
* **the linear-Gaussian posterior** (x-free, with the problem's sampler): the prior taken as Gaussian
  (mean and covariance from its draws), the exact posterior mean, per-node std and 90 % intervals
  (:func:`pdeinv.training.references.gaussian_posterior`); with ``x``, the intervals' coverage and width:
  what a run's calibrated posterior (``metrics["posterior"]``) is compared with;
* with ``x``: **Tikhonov with the best common α** (``tikhonov_best_common_alpha``: one α for every
  row, chosen with the file's x on a grid; Morozov's α, chosen per row, can beat it), the **linear
  MMSE fitted on the file's x** (``mmse_file_x``, :func:`pdeinv.training.references.mmse`, noise
  variance from the level above: the best linear estimate for data distributed as the file's rows,
  up to the sampling error of their covariance, so the prior Wiener estimate can beat it on few
  rows) and the data's **model mismatch** ``mean ‖P x − y‖/‖y‖``
  (:func:`pdeinv.training.data.model_mismatch`).

Observations with no signal (no noise level declared, and the one estimated from the file makes Morozov's
principle accept the estimate 0: :func:`pdeinv.inverse.noise.signal_free`) are refused before any solve
(exit 3, one line; ``--accept-bad``: a warning, exit 0).

Prints one line per solve (x-error with x, and the relative residual ``mean ‖P x̂ − y‖/‖y‖``) and
writes them to ``--out`` (JSON) if given; x-errors are relative L²(Ω) over all the file's rows
(a run's ``x_err`` is over its test rows: compare on the same rows).
"""

from __future__ import annotations

import json
import sys

from pdeinv.util.outpaths import output_file

from . import (
    FAILED,
    PLAIN_INT,
    BadData,
    add_set_argument,
    build_problem,
    parse_sets,
    set_threads,
)

ORDER = 2


def cmd_classical(args) -> int:
    import numpy as np

    from pdeinv.fem.forms import relative_norms
    from pdeinv.physics.nonlinear import is_linear
    from pdeinv.problem.units import units_of
    from pdeinv.training.data import no_signal, read_meta, read_noise, read_npz
    from pdeinv.util.files import atomic_write

    # the one output-path policy (pdeinv.util.outpaths): resolved, folder created, never the --data file, a
    # run's file or (without --overwrite) any existing file
    out = None if args.out is None else output_file(args.out, "--out", [("--data", args.data)],
                                                    suffixes=(".json",), overwrite=args.overwrite)
    set_threads(args.threads)
    problem = build_problem("classical", args.problem, args.set)
    y, x = read_npz(args.data, problem.operator.n_out, problem.N)
    c = units_of(y, problem.operator, f"--data {args.data!r}")  # solved on y / c, answered ×c
    y, x = y / c, None if x is None else x / c
    declared = read_meta(args.data, problem.points).get("noise")
    chosen = "noise" in parse_sets(args.set)  # --set noise=0 declares noise-free data: no estimate
    # with x the level is what P x leaves (noise δ: mismatch δ/√(1+δ²)); without, the spectral tail a linear
    # smoothing map leaves (none of a nonlinear map): the median singular value, signal where the rows' few
    # observations are all signal (heat_1d n=8 read 0.148 on exact data)
    guess = _from_mismatch(problem, x, y)
    _unrelated(args, problem, x, y, guess, problem.noise or declared or 0.0)
    guess = read_noise(y, problem.operator) if guess is None else guess
    why = None if problem.noise or declared or chosen else no_signal(guess, len(y))
    if why is not None:
        return _no_signal(args, why)
    noise = problem.noise or declared or (0.0 if chosen else guess)
    source = "the problem's" if problem.noise or chosen else "the file's" if declared else \
        "estimated from the file" if is_linear(problem.operator) else "the problem's"
    if not noise:  # rounding is no noise level (pdeinv.inverse.noise.ROUNDING_LEVEL): the noise-free branch
        source += " (noise-free)"

    def err(xh) -> dict:
        """x-error (with x), the relative residual ``mean ‖P x̂ − y‖/‖y‖`` and the rms amplitude."""
        res = relative_norms(np.linalg.norm(problem.operator.forward(xh) - y, axis=1),
                             np.linalg.norm(y, axis=1))  # a zero row: against the rows' rms norm
        return {"x_err": None if x is None else float(np.mean(problem.relative_error(xh, x))),
                "residual": float(np.mean(res)), "amplitude": float(np.sqrt(np.mean(np.sum(xh**2, axis=1))))}

    rows = _solves(problem, y, x, noise, source, err)
    _finite(rows)
    assumed = problem.noise or declared or 0.0  # the level train and predict judge the mismatch at
    failed = _failed(problem, rows, x, y, assumed, *_declared(args, problem, declared))
    _in_units(rows, c)
    for name, value in rows.items():
        print(f"{problem.name} {name}: {json.dumps(value)}")
    rows["failed"] = failed
    if out is not None:
        text = json.dumps({"problem": problem.name, "data": str(args.data), "rows": len(y), **rows}, indent=2)
        atomic_write(out, lambda fh: fh.write(text.encode()))
    sys.stdout.flush()
    if rows["failed"]:
        kind = "warning" if args.accept_bad else "error"
        print(f"pdeinv classical: {kind}: {rows['failed']}" + ("" if args.accept_bad else
              "; --accept-bad ends with exit code 0"), file=sys.stderr)
        return 0 if args.accept_bad else FAILED
    return 0


#: the figures of a solve in the data's units (the others are relative)
ABSOLUTE = ("amplitude", "std_mean", "width_90")


def _in_units(rows: dict, c: float) -> None:
    """``rows`` solved on the file's rows divided by ``c`` (:func:`pdeinv.problem.units.units_of`), in the
    file's units: the :data:`ABSOLUTE` figures times ``c``, and ``units`` recorded where ``c ≠ 1``."""
    if c == 1.0:
        return
    for value in rows.values():
        for key in ABSOLUTE:
            if isinstance(value, dict) and key in value:
                value[key] *= c
    rows["units"] = c


def _no_signal(args, why: str) -> int:
    """Observations that are noise all through (:func:`pdeinv.training.data.no_signal`, ``why``): exit 3 and
    one line (:class:`BadData`), or with ``--accept-bad`` a warning and exit 0; nothing is solved."""
    why = f"--data {args.data!r} {why} (--set noise=… declares a level instead)"
    if not args.accept_bad:
        raise BadData(f"{why}; --accept-bad ends with exit code 0")
    print(f"pdeinv classical: warning: {why}; nothing solved (--accept-bad)", file=sys.stderr)
    return 0


def _unrelated(args, problem, x, y, guess, noise: float) -> None:
    """y no closer to ``P x`` than to 0 (``guess``: :func:`_from_mismatch` read no level): every solve would
    be meaningless, so :class:`BadData` (exit 3) before any, with :func:`_failed`'s line (not with
    ``--accept-bad``)."""
    from pdeinv.training.data import model_mismatch

    if x is None or guess is not None or args.accept_bad:
        return
    why = _failed(problem, {"model_mismatch": model_mismatch(problem.operator, x, y)}, x, y, noise)
    if why is not None:
        raise BadData(f"{why}; nothing solved (--accept-bad solves anyway)")


def _from_mismatch(problem, x, y) -> float | None:
    """The relative noise level ``δ`` a file's own ``x`` show: ``f = mean ‖P x − y‖/‖y‖`` is ``δ/√(1+δ²)`` for
    ``y = P x + δ·rms(P x)·ε``, so ``δ = f/√(1 − f²)``; 0 at rounding (:data:`~pdeinv.inverse.noise.
    ROUNDING_LEVEL`). ``None`` without ``x``, or where ``y`` is no closer to ``P x`` than to 0 (not this
    physics' data: the spectral reading then, and the mismatch check says so)."""
    import numpy as np

    from pdeinv.inverse.noise import ROUNDING_LEVEL
    from pdeinv.training.data import model_mismatch

    if x is None:
        return None
    f = model_mismatch(problem.operator, x, y)
    if not np.isfinite(f) or f >= 1:
        return None
    return 0.0 if f <= ROUNDING_LEVEL else float(f / np.sqrt(1 - f * f))


def _solves(problem, y, x, noise: float, source: str, err) -> dict:
    """The classical solves of ``y`` (module docstring), each row measured by ``err``."""
    from pdeinv.physics.nonlinear import is_linear

    if not is_linear(problem.operator):  # no matrix: the per-sample Gauss–Newton references
        return _nonlinear_solves(problem, y, x, noise, source, err)
    import numpy as np

    from pdeinv.inverse import NOISE_FREE_REL_ALPHA, Discrepancy, default_alpha, default_inverse
    from pdeinv.methods.targets import SpectralWiener
    from pdeinv.training import references
    from pdeinv.training.data import model_mismatch

    zeros = np.zeros((len(y), problem.N))
    rows = {"noise": {"level": noise, "source": source}}
    if noise > 0:
        inv = default_inverse(problem.operator, getattr(problem, "disc", None), noise, Discrepancy(noise))
        rows["tikhonov_morozov"] = err(inv(y, zeros))
        fitted = SpectralWiener().fit(problem, y, noise)
        if fitted is not None:
            rows["wiener_target"] = {**err(problem.inverse(fitted(y), zeros)), "kept": fitted.info["kept"],
                                     "modes": fitted.info["modes"]}
    else:
        inv = default_inverse(problem.operator, getattr(problem, "disc", None), 0.0, default_alpha(0.0))
        rows["tikhonov_noise_free"] = {**err(inv(y, zeros)), "alpha_rel": NOISE_FREE_REL_ALPHA}
    if getattr(problem, "sampler", None) is not None:
        estimate, info = references.prior_wiener(problem, y, noise)
        rows["prior_wiener"] = {**err(estimate(y)), **info}
        post, info = references.gaussian_posterior(problem, noise)
        mean = post.mean(y)
        rows["gaussian_posterior"] = {**err(mean), **info, "std_mean": float(post.std.mean())}
        if x is not None:
            lo, hi = post.interval(y, 0.9)
            rows["gaussian_posterior"].update(coverage_90=float(np.mean((lo <= x) & (x <= hi))),
                                              width_90=float(np.mean(hi - lo)))
    if x is not None:
        best = references.tikhonov_best(problem, y, x)
        rows["tikhonov_best_common_alpha"] = {"x_err": best["x_err"], "alpha_rel": best["alpha_rel"]}
        if len(x) >= 2:  # the linear MMSE with the file's own x as the prior: an oracle like the α above
            sigma2 = noise**2 * float(np.mean(problem.operator.forward(x) ** 2))
            estimate, info = references.mmse(problem, x, sigma2)
            rows["mmse_file_x"] = {**err(estimate(y)), "sigma2_rule": info["sigma2_rule"]}
        rows["model_mismatch"] = model_mismatch(problem.operator, x, y)
    return rows



def _nonlinear_solves(problem, y, x, noise: float, source: str, err) -> dict:
    """A nonlinear map's classical references (:func:`pdeinv.training.references.levenberg_marquardt`):
    the iteration stopped by Morozov's discrepancy principle at the noise level, and with ``x`` the best
    common α of :data:`~pdeinv.training.references.LM_ALPHAS` (an oracle), timed per sample."""
    from pdeinv.training import references
    from pdeinv.training.data import model_mismatch

    rows = {"noise": {"level": noise, "source": source}}
    X, info = references.levenberg_marquardt(problem, y, references.LM_ALPHAS[1], noise=noise)
    rows["gauss_newton_morozov" if noise else "gauss_newton"] = {**err(X), **info}
    if x is not None:
        tried = [(err(Xa), ia) for Xa, ia in (references.levenberg_marquardt(problem, y, a)
                                             for a in references.LM_ALPHAS)]
        best, info = min(tried, key=lambda t: t[0]["x_err"])
        rows["gauss_newton_best_common_alpha"] = {**best, **info}
        rows["model_mismatch"] = model_mismatch(problem.operator, x, y)
    return rows

def _finite(rows: dict) -> None:
    """Refuse to print NaN or Infinity (not JSON): a solve whose number is not finite is a numerical
    failure (exit 1), named."""
    import math

    from pdeinv.errors import NumericalError

    for name, value in rows.items():
        for key, v in (value.items() if isinstance(value, dict) else [("", value)]):
            if isinstance(v, float) and not math.isfinite(v):
                what = f"{name} {key}".strip()
                raise NumericalError(f"the {what} is {v}: that solve failed on this file (non-finite rows? "
                                     "check the data with numpy.isfinite)")


def _declared(args, problem, declared) -> tuple[float | None, str]:
    """``(level, by)``: the noise level the user declared, the file's or ``--set noise=…`` (``by`` names
    the flag), which the file's x are checked against; ``(None, "")`` for none."""
    said = parse_sets(args.set).get("noise") if problem.noise and not declared else None
    if said:
        return problem.noise, f"--set noise={said}"
    return (None if problem.noise else declared), ""


def _failed(problem, rows: dict, x, y, noise: float, declared: float | None = None,
            by: str = "") -> str | None:
    """Why the classical solves cannot be right, or None: with x, a model mismatch far above the noise
    level ``noise`` the problem or the file declares (beyond :func:`pdeinv.training.data.mismatch_limit`, the
    limit of ``train`` and ``predict`` too, which read no level off the file: a level estimated from the y
    absorbed a mismatch of another κ; another physics or other settings), far below the level the file
    ``declared``
    (:func:`~pdeinv.training.data.below_noise`), or every estimate no better than zero (x_err ≥ 1);
    without x, estimates over :data:`pdeinv.training.verdict.AMPLITUDE` times the prior's rms amplitude."""
    import numpy as np

    from pdeinv.training.data import below_noise, mismatch_limit, zero_rows
    from pdeinv.training.verdict import AMPLITUDE, WORSE_THAN_ZERO

    mismatch = rows.get("model_mismatch")
    if mismatch is not None and declared and (why := below_noise(mismatch, declared, by)) is not None:
        return why if by else f"the file's noise level: {why}"
    if x is not None and (zero := zero_rows(y, x)) is not None:
        return f"in the file, {zero}: observations missing? (P x of a nonzero x is not zero); drop those rows"
    if mismatch is not None and not mismatch <= mismatch_limit(noise):
        declare = "" if noise else " (noisy data: declare the level with --set noise=… or a 'noise' array)"
        return (f"the file's y differ from this problem's P x by {mismatch:.3g} (mean ‖P x − y‖/‖y‖), far "
                f"above the noise level {noise:g}{declare}: the data come from another physics or other "
                "settings (κ, T, the mesh?), so no estimate here means anything")
    errs = {k: v["x_err"] for k, v in rows.items() if isinstance(v, dict) and v.get("x_err") is not None}
    if errs and min(errs.values()) >= WORSE_THAN_ZERO:
        return f"every classical estimate is no better than zero: x_err {min(errs.values()):.3g} at best"
    if x is None and problem.sampler is not None:  # per unit of the observations' (a file in other units)

        def rms(a):
            return float(np.sqrt(np.mean(np.sum(np.asarray(a, dtype=float) ** 2, axis=1))))

        x_ref, y_ref = problem.sample(len(y), 0)
        units = rms(y) / max(rms(y_ref), 1e-300)
        ref = rms(x_ref) * units
        worst = max((v.get("amplitude", 0.0) for v in rows.values() if isinstance(v, dict)), default=0.0)
        if worst / max(ref, 1e-300) >= AMPLITUDE:
            return (f"the estimates reach {worst / ref:.3g}× the prior's rms amplitude, per unit of the "
                    "observations': no field of this problem's prior explains these observations (another "
                    "physics or settings?)")
    return None


def add_parser(sub) -> None:
    c = sub.add_parser("classical", help="Tikhonov (Morozov α, best α with x), the Wiener target, the "
                                         "MMSE and the model mismatch of a data file: what a trained run is "
                                         "compared with")
    c.add_argument("problem")
    c.add_argument("--data", required=True, metavar="FILE.npz", help="y (B, m), optionally x (B, N)")
    c.add_argument("--out", default=None, metavar="FILE.json", help="also write the numbers as JSON")
    c.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    add_set_argument(c)
    c.add_argument("--threads", type=PLAIN_INT, default=1, help="threads of torch and of numpy/scipy's BLAS")
    c.add_argument("--accept-bad", action="store_true",
                   help="exit 0 even when the solves cannot be right (else exit code 3 and one line: a model "
                        "mismatch far above the noise, every estimate no better than zero, estimates over "
                        "100x the prior's amplitude without x, or observations with no signal); the numbers "
                        "are printed and written either way (none for observations with no signal)")
    c.set_defaults(func=cmd_classical)
