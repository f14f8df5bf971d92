"""Run folders: what ``pdeinv train --out DIR`` writes, and :func:`load_run` to rebuild its network.

``DIR/run.json`` records what rebuilds the run's problem and network::

    {"format": "pdeinv-run", "version": 1,
     "problem": "heat_2d" | "/abs/path/module.py", "overrides": {"kappa": "0.02", ...},
     "network": {"kind": "default"} | {"kind": "mlp", "hidden": [64, 64]}
                | {"kind": "reduced", "k_in": 256, "k_out": 256, "body": "linear"}
                (+ "units": c when the data were divided by c: pdeinv.problem.units),
     "model_sha256": "<hex digest of model.pt>",
     "posterior_sha256": "<hex digest of posterior.npz>" | null,
     "fingerprint": {"unknowns": N, "observations": m, "x": [...], "y": [...]}
                (pdeinv.problem.fingerprint: load_run refuses a module edited into another problem),
     "record_sha256": "<hex digest of the fields above>"}

and ``DIR/model.pt`` the network's state dict, the fitted whitening / input scaling
buffers included. ``load_run(DIR)`` calls ``load_problem(problem, **overrides)``,
builds the network from :data:`NETWORKS` and loads the state dict (strict). Both
files are written atomically (:func:`pdeinv.util.files.atomic_write`).

:data:`OUTPUTS` lists every file ``pdeinv train`` writes into ``DIR``;
:func:`clear_outputs` removes those (and their stale temporaries), never other files. Before its first
file, ``pdeinv train`` marks ``DIR`` as a run (:data:`pdeinv.util.outpaths.RUN_MARKER`): only a folder so
marked (or holding a ``run.json`` of this format) is a run that ``--overwrite`` may replace
(:func:`pdeinv.util.outpaths.run_folder`).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import warnings
from pathlib import Path

from ..util.files import atomic_write, remove_stale_temporaries
from ..util.outpaths import RUN_FORMAT, RUN_OUTPUTS

FORMAT, VERSION = RUN_FORMAT, 1
RUN_FILE, MODEL_FILE = "run.json", "model.pt"
#: the calibrated posterior of the run's network (:class:`pdeinv.posterior.conformal.Calibration`), when the
#: run had a calibration stage
POSTERIOR_FILE = "posterior.npz"

#: every file ``pdeinv train`` writes into its ``--out`` folder (``.lock`` is the run lock's own, the
#: marker :data:`pdeinv.util.outpaths.RUN_MARKER` the folder's: it stays when ``--overwrite`` clears these);
#: the output policy's own list (:data:`pdeinv.util.outpaths.RUN_OUTPUTS`), which names these files too
OUTPUTS = RUN_OUTPUTS
assert {MODEL_FILE, RUN_FILE, POSTERIOR_FILE} <= set(OUTPUTS)


def _mlp(problem, hidden):
    from ..nets import MLP

    return MLP(problem.operator.n_out, problem.operator.n_in, hidden=tuple(hidden))


def _from_nets(name: str):
    """A :data:`NETWORKS` entry ``pdeinv.nets.<name>(**settings)(problem)`` (torch imported when used)."""
    def build(problem, **settings):
        from .. import nets

        return getattr(nets, name)(**settings)(problem)
    return build


#: network kinds: ``kind -> (problem, **settings) -> nn.Module`` (untrained; the state dict fills it)
NETWORKS = {
    "default": lambda problem, **settings: problem.model(**settings),
    "linear": lambda problem, **settings: __import__("pdeinv.nets").nets.linear_default(problem, **settings),
    "mlp": _mlp,
    "modal": _from_nets("modal"),
    "reduced": _from_nets("reduced"),
    "unet": _from_nets("unet"),
    "whitened": _from_nets("whitened"),
}


def _folded(model):
    """``model`` with its input transform folded into its weights where that saves numbers (a copy;
    :meth:`pdeinv.nets.protocol.Network.fold`): the same function, a smaller ``model.pt``."""
    import copy

    from ..nets.protocol import declared
    from ..problem.units import unwrap

    folded = copy.deepcopy(model)
    return folded if declared(unwrap(folded)[0]).fold() else model


def _spec(network_spec, model) -> dict:
    """What run.json records of ``model``: ``network_spec`` (``None``: the spec the Trainer built the
    network with, a data file's base included, else ``{"kind": "default"}``), checked, with the kind of
    its correction and its units (:mod:`pdeinv.problem.units`)."""
    from ..problem.units import unwrap

    inner, units = unwrap(model)
    if network_spec is None:
        network_spec = getattr(inner, "network_spec", {"kind": "default"})
    if not isinstance(network_spec, dict) or network_spec.get("kind") not in NETWORKS:
        raise ValueError(f"network_spec={network_spec!r} is not allowed; expected a dict with 'kind' one of "
                         f"{', '.join(map(repr, NETWORKS))}")
    spec = _with_unet_shape(_with_correction(network_spec, inner), inner)
    return {**spec, **({"units": units} if units != 1.0 else {})}


#: the U-Net shape of a ``"unet"`` run recorded before run.json held it: two levels, one convolution up
_LEGACY_UNET = {"depth": 2, "up_convs": 1}


def _with_unet_shape(spec: dict, model) -> dict:
    """``spec`` of a ``"unet"`` network with its U-Net's ``depth`` and ``up_convs``, which a reloaded run
    must be built with (the default depth follows the grid, and has changed)."""
    from ..nets.unet import MeshUNet

    if spec.get("kind") != "unet":
        return spec
    found = next((m for m in model.modules() if isinstance(m, MeshUNet)), None)
    if found is None:
        return spec
    return {**spec, "depth": found.unet.levels, "up_convs": found.unet.up_convs}


def _with_correction(spec: dict, model) -> dict:
    """``spec`` with the kind of ``model``'s nonlinear correction (:mod:`pdeinv.nets.corrections`), which
    a reloaded default network must be built with."""
    from ..nets.refine import Refined

    if spec.get("kind") != "default" or not isinstance(model, Refined):
        return spec
    return {**spec, "correction": model.correction_kind}


def network(problem, spec: dict):
    """A fresh network of ``spec`` (``{"kind": ..., **settings}``) for ``problem``; with ``"units": c``,
    answered in the units of data divided by ``c`` for training (:mod:`pdeinv.problem.units`)."""
    from ..problem.units import wrap

    spec = dict(spec)
    kind, units = spec.pop("kind", None), spec.pop("units", 1.0)
    if kind not in NETWORKS:
        raise ValueError(f"network kind {kind!r} is not known; expected one of {', '.join(NETWORKS)}")
    if isinstance(units, bool) or not isinstance(units, (int, float)) or not 0 < units < float("inf"):
        raise ValueError(f"network units {units!r} are not allowed; expected a positive number")
    return wrap(NETWORKS[kind](problem, **spec), float(units))


def problem_spec(name_or_path: str) -> str:
    """A problem name as given, or a module path made absolute (the run can be loaded from elsewhere).

    Only a built-in stays a name: a name found anywhere else (the current folder, its ``problems/``,
    ``PDEINV_PROBLEMS``: :func:`pdeinv.problem.find_module`) is stored as its module's absolute path. By
    name, ``pdeinv predict`` run from another folder said "unknown problem", and one run without the
    variable loaded the built-in of the same name (another physics, silently where the shapes agree)."""
    spec = os.fspath(name_or_path)
    if spec.endswith(".py") or os.sep in spec or "/" in spec:
        return str(Path(spec).resolve())
    from ..problem.definition import builtin_dir, find_module

    try:
        path = find_module(spec).resolve()
    except (ValueError, FileNotFoundError):
        return spec
    return spec if path.parent == builtin_dir().resolve() else str(path)


def save_run(out: str | os.PathLike, problem, overrides: dict | None = None, network_spec: dict | None = None,
             model=None, posterior=None, *, overwrite: bool = False) -> Path:
    """Write ``out/run.json`` and ``out/model.pt`` (module docstring), and ``out/posterior.npz`` when
    ``posterior`` (``result.posterior``) is given; returns ``out``.

    ``problem``: the name or module path the run's problem is loaded from (a :class:`~pdeinv.Problem`
    stands for its ``name`` and, without ``overrides``, for its settings that differ from the module's
    defaults), ``overrides`` its settings (default none), ``network_spec`` the network's
    :data:`NETWORKS` entry (default: the one the Trainer built ``model`` with, else ``{"kind": "default"}``,
    ``problem.model()``), ``model`` the trained
    network (``result.model``), e.g. ``save_run("runs/a", "heat_2d", model=result.model)``. The run is
    checked as :func:`load_run` will read it: the problem loads with ``overrides``, ``model`` maps its
    observations to its unknowns, ``posterior`` (a :class:`~pdeinv.posterior.Calibration` or ``None``) is
    for them. ``out`` follows the output-path policy (:mod:`pdeinv.util.outpaths`,
    :func:`~pdeinv.util.outpaths.run_folder`): created with its parents; refused in one line when it cannot
    be written, is a non-empty folder that holds no pdeinv run, or holds another run's files (those of
    :data:`OUTPUTS`) and ``overwrite`` is not ``True`` (then its ``run.json`` and ``model.pt`` are
    replaced; ``pdeinv train`` passes it for the ``--out`` it checked before the run).
    """
    import torch

    from ..problem.definition import Problem
    from ..problem.fingerprint import fingerprint
    from ..training import arguments as _arguments
    from ..util.outpaths import run_folder

    given = problem if overrides is None and isinstance(problem, Problem) else None  # its own settings
    problem, overrides = _saved_problem(out, problem, overrides)
    model = _arguments.model(model, optional=False)
    _arguments.flag(overwrite, "overwrite")
    recorded = network_spec is not None or hasattr(_unwrapped(model), "network_spec")
    network_spec = _spec(network_spec, model)
    _refuse_another_run(run_folder(out, "out", replace=True, outputs=OUTPUTS, create=False), overwrite)
    overrides, built = _check_loads(problem, overrides, model, posterior, given)  # before the folder is made
    if not recorded:  # a network no spec names: the default one must be what load_run rebuilds
        _rebuilds(problem, overrides, network_spec, model)
    out = run_folder(out, "out", replace=True, outputs=OUTPUTS)
    buffer = io.BytesIO()
    torch.save(_folded(model).state_dict(), buffer)
    weights = buffer.getvalue()
    data = None if posterior is None else posterior.to_bytes()
    record = {"format": FORMAT, "version": VERSION, "problem": problem_spec(problem),
              "overrides": {k: str(v) for k, v in overrides.items()}, "network": network_spec,
              "model_sha256": hashlib.sha256(weights).hexdigest(),
              "posterior_sha256": None if data is None else hashlib.sha256(data).hexdigest(),
              "fingerprint": fingerprint(built)}  # load_run refuses the name once it makes another problem
    record["record_sha256"] = _record_digest(record)
    text = json.dumps(record, indent=2).encode()
    atomic_write(out / MODEL_FILE, lambda fh: fh.write(weights))
    if data is not None:
        atomic_write(out / POSTERIOR_FILE, lambda fh: fh.write(data))
    elif (out / POSTERIOR_FILE).is_file():  # an earlier run's: not this model's
        (out / POSTERIOR_FILE).unlink()
    atomic_write(out / RUN_FILE, lambda fh: fh.write(text))  # last: the record of files that are there
    return out


def _saved_problem(out, problem, overrides) -> tuple:
    """:func:`save_run`'s ``out``, ``problem`` and ``overrides`` checked: ``(problem name or path,
    overrides dict)``."""
    from ..problem.definition import Problem
    from ..training import arguments as _arguments

    if isinstance(problem, Problem):
        problem = problem.name
    if not isinstance(out, (str, os.PathLike)):  # save_run(result, "runs/a"): the arguments swapped
        raise TypeError(f"{_arguments._named('out', out)} is {_arguments._kind(out)}; expected the run's "
                        "folder (str or path): save_run(out, problem, model=result.model)")
    if not isinstance(problem, (str, os.PathLike)) or not os.fspath(problem).strip():
        # the kind, not the repr: a Result's or a network's repr is many lines
        hint = "; for a training Result: save_run(out, problem, model=result.model, " \
            "posterior=result.posterior)" if _arguments._is_result(problem) else ""
        named, kind = _arguments._named("problem", problem), _arguments._kind(problem)
        raise TypeError(f"{named} is {kind}; expected the problem's name or module path (str, e.g. "
                        f"'heat_2d'), or the Problem{hint}")
    overrides = {} if overrides is None else overrides
    if not isinstance(overrides, dict):
        raise TypeError(f"overrides={overrides!r} is not allowed; expected a dict of the problem's settings")
    return problem, overrides


def _unwrapped(model):
    from ..problem.units import unwrap

    return unwrap(model)[0]


def _rebuilds(problem, overrides: dict, spec: dict, model) -> None:
    """A ``ValueError`` unless the network ``spec`` builds takes ``model``'s state dict (what
    :func:`load_run` will load into it)."""
    from ..problem.definition import load_problem

    try:
        rebuilt = network(load_problem(problem, **overrides), spec)
        _load_state(rebuilt, _folded(model).state_dict(), "save_run")
    except ValueError as err:
        why = str(err).split(" (", 1)[-1].rsplit("): ", 1)[0]
        raise ValueError(f"save_run: model ({type(_unwrapped(model)).__name__}) is not the network run.json "
                         f"would record ({json.dumps(spec)}: {why}), so load_run could not rebuild it; save "
                         "a network of pdeinv.nets (or the Trainer's), or pass its network_spec") from None


def _check_loads(problem, overrides: dict, model, posterior, given=None) -> tuple:
    """What :func:`load_run` will check, checked before anything is written: the problem loads with
    ``overrides`` (its settings' names and values), ``model`` maps its observations to its unknowns (two
    zero rows through it: :func:`pdeinv.training.arguments.fits`), ``posterior`` is for them. ``given``: the
    :class:`~pdeinv.Problem` passed without overrides, whose settings that differ from its module's
    defaults become the overrides (``load_problem('heat_1d', n=8)`` is saved as ``n=8``); ``(overrides,
    problem)``, the problem as load_run rebuilds it."""
    from ..posterior.conformal import Calibration
    from ..problem.definition import first_line, load_problem
    from ..problem.trained import differ, trained_for
    from ..training import arguments as _arguments

    if posterior is not None and not isinstance(posterior, Calibration):
        raise TypeError(f"{_arguments._named('posterior', posterior)} is {_arguments._kind(posterior)}; "
                        "expected None or a pdeinv.posterior.Calibration (result.posterior)")
    def build(overrides):
        try:
            return load_problem(problem, **overrides)
        except (ValueError, TypeError, FileNotFoundError) as err:
            raise ValueError(f"problem={os.fspath(problem)!r} with overrides={overrides!r} does not load "
                             f"({first_line(err, 200)}): load_run could not rebuild this run") from None

    built = build(overrides)
    own = {} if given is None else {k: v for k, v in given.settings.items()
                                    if k in built.settings and differ(built.settings[k], v)}
    if own:
        overrides, built = own, build(own)
    trained_for(model, built)
    _arguments.fits(model, built)
    if posterior is not None and posterior.scale.shape != (built.N,):
        raise ValueError(f"posterior is for {posterior.scale.shape[0]} unknowns; the run's problem has "
                         f"{built.N}: not this model's posterior")
    if posterior is not None:
        from ..posterior.predictive import forward

        posterior.check_network(lambda rows: forward(model, rows))
    return overrides, built


def _record_digest(record: dict) -> str:
    """The sha256 of what ``run.json`` records (``problem``, ``overrides``, ``network`` and the digests of
    ``model.pt`` and ``posterior.npz``): an edit of any (another κ for the trained model, a digest deleted)
    is refused by :func:`load_run`."""
    fields = ("problem", "overrides", "network", "model_sha256", "posterior_sha256")
    fields += ("fingerprint",) if "fingerprint" in record else ()  # records before it keep their digest
    return hashlib.sha256(json.dumps({k: record.get(k) for k in fields}, sort_keys=True).encode()).hexdigest()


def _refuse_another_run(out: Path, overwrite: bool) -> None:
    """Refuse ``out`` holding another run's files (:data:`OUTPUTS`) unless ``overwrite``."""
    from ..util.outpaths import OutputPathError

    found = existing_outputs(out)
    if not found or overwrite:
        return
    raise OutputPathError(f"out {str(out)!r} holds another pdeinv run ({', '.join(found)}); pass "
                          "overwrite=True to replace it, or choose another out")


def load_posterior(run_dir, problem=None):
    """The run's :class:`~pdeinv.posterior.conformal.Calibration`, or ``None`` when it has none; a file
    that does not fit the run's problem (``problem``) is a ``ValueError``."""
    from .._checks import problem as checked
    from ..posterior.conformal import Calibration

    run = _run_path(run_dir, "run_dir")
    if problem is not None:
        checked(problem)
    if not run.is_dir():
        raise ValueError(f"run folder {os.fspath(run)!r} is not a directory; expected the --out DIR of a "
                         "finished `pdeinv train`")
    if not (run / RUN_FILE).is_file():  # a folder of anything else has no posterior, and no run either
        raise ValueError(f"run folder {os.fspath(run)!r} holds no {RUN_FILE}: not a pdeinv run (is it the "
                         "--out DIR of a finished `pdeinv train`?)")
    path = run / POSTERIOR_FILE
    digest = _posterior_digest(run, path)
    if not path.is_file():
        return None
    try:
        cal = Calibration.load(path)
    except Exception as err:  # noqa: BLE001  (a truncated, edited or foreign file)
        why = str(err) if isinstance(err, ValueError) and str(err).startswith("its ") else type(err).__name__
        raise ValueError(f"{os.fspath(path)!r} is not a pdeinv posterior ({why}); rerun `pdeinv train`") \
            from None
    if problem is not None and cal.scale.shape != (problem.N,):
        raise ValueError(f"{os.fspath(path)!r} is for {cal.scale.shape[0]} unknowns; the run's problem has "
                         f"{problem.N}: rerun `pdeinv train`")
    if problem is not None:
        _recorded_problem(run, problem)
    if digest is not None and _sha256(path) != digest:
        raise ValueError(f"run folder {os.fspath(run)!r}: {POSTERIOR_FILE} is not the posterior its "
                         f"{RUN_FILE} was written with (its sha256 differs: another run's posterior, or an "
                         "edited file); copy a run's files together, or rerun `pdeinv train`")
    return cal


def load_run(run_dir):
    """``(problem, model)`` of a finished ``pdeinv train`` run folder (``model`` in eval mode).

    ``TypeError`` when ``run_dir`` is not a path; ``ValueError`` when it is not a folder, has no
    ``run.json`` or ``model.pt``, a field of ``run.json`` is not what it should be, or they do not fit
    together.
    """
    import torch

    from ..problem.definition import load_problem
    from ..problem.fingerprint import changed

    run = _run_path(run_dir, "run_dir")
    where = f"run folder {os.fspath(run)!r}"
    if not run.is_dir():
        raise ValueError(f"{where} is not a directory; expected the --out DIR of a finished `pdeinv train`")
    missing = [name for name in (RUN_FILE, MODEL_FILE) if not (run / name).is_file()]
    if missing:
        raise ValueError(f"{where} holds no {' or '.join(missing)}: no trained model "
                         "(is it the --out DIR of a finished `pdeinv train`?)")
    record = _record(run, where)
    problem = load_problem(record["problem"], **record["overrides"])
    digest = record.get("record_sha256")  # records of earlier pdeinv versions have none
    edited = digest is not None and digest != _record_digest(record)
    why = None if record.get("fingerprint") is None else changed(problem, record["fingerprint"])
    if why is not None and edited:  # the record's own settings changed: say so, with what they now build
        raise ValueError(_edited(where, f"; its settings now build another problem: {why}"))
    if why is not None:  # before the model: its shapes would blame model.pt, or fit another physics
        raise ValueError(f"{where}: problem {record['problem']!r} with {RUN_FILE}'s settings is not the "
                         f"one the run was trained on ({why}: an edited module, setting or mesh?); restore "
                         "it, or rerun `pdeinv train`")
    try:
        spec = record["network"]
        legacy = isinstance(spec, dict) and spec.get("kind") == "unet" and "depth" not in spec
        model = network(problem, {**spec, **_LEGACY_UNET} if legacy else spec)
    except (TypeError, ValueError) as err:  # a kind's settings edited: an unknown name, a wrong value
        first = (str(err).strip().splitlines() or [type(err).__name__])[0][:160]
        raise ValueError(f"{where}: {RUN_FILE}'s 'network' {json.dumps(record['network'])[:80]} builds no "
                         f"network ({first}); rerun `pdeinv train`") from None
    try:
        with warnings.catch_warnings():  # torch's note on a pickle protocol names its own source file
            warnings.simplefilter("ignore", UserWarning)
            state = torch.load(run / MODEL_FILE, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001  (torch's unpickling errors are pages long and differ by version)
        raise ValueError(f"{where}: {MODEL_FILE} cannot be read as a torch state dict (damaged, or not a "
                         "file pdeinv wrote); rerun `pdeinv train`") from None
    _check_model_file(run / MODEL_FILE, record.get("model_sha256"), where)
    _load_state(model, state, where)
    if edited:  # an edit the checks above let through
        raise ValueError(_edited(where))
    from ..problem.trained import mark_trained

    mark_trained(model, problem)  # save_run and predict refuse it with another problem
    return problem, model.eval()


def _edited(where: str, what: str = "") -> str:
    """The one line for a ``run.json`` whose fields no longer match its ``record_sha256``."""
    return (f"{where}: {RUN_FILE} was edited after the run (its problem, overrides, network or file digests "
            f"no longer match its record_sha256{what}): the model was trained with the ones recorded; "
            f"restore {RUN_FILE}, or rerun `pdeinv train` with the settings you want")


def _fingerprint_like(value) -> bool:
    numbers = (int, float)
    return (isinstance(value, dict) and all(type(value.get(k)) is int for k in ("unknowns", "observations"))
            and all(isinstance(value.get(k), list) and len(value[k]) == 3
                    and all(isinstance(v, numbers) and not isinstance(v, bool) for v in value[k])
                    for k in ("x", "y")))


def _run_path(value, name: str) -> Path:
    """``value`` as a :class:`~pathlib.Path`; anything but a ``str`` or ``os.PathLike`` (``None``, a number,
    ``bytes``) is a ``TypeError`` naming ``name``."""
    if not isinstance(value, (str, os.PathLike)) or isinstance(os.fspath(value), bytes):
        raise TypeError(f"{name}={value!r:.60} is {type(value).__name__}; expected a path (str or "
                        "os.PathLike): the --out DIR of a finished `pdeinv train`")
    return Path(value)


def _record(run: Path, where: str) -> dict:
    """``run/run.json`` read and its fields checked (module docstring): one ``ValueError`` naming the
    field and what it should be, not a ``TypeError`` from deep inside :func:`load_run`."""
    try:
        record = json.loads((run / RUN_FILE).read_text())
        assert record.get("format") == FORMAT and {"problem", "overrides", "network"} <= set(record)
    except (ValueError, AssertionError, AttributeError):
        raise ValueError(f"{where}: {RUN_FILE} is not a pdeinv run record; rerun `pdeinv train`") from None
    version = record.get("version", VERSION)  # a run of a later pdeinv may mean its fields otherwise
    if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= VERSION:
        raise ValueError(f"{where}: {RUN_FILE} has version {version!r}; this pdeinv reads run records of "
                         f"version 1 to {VERSION}: use the pdeinv that wrote it, or rerun `pdeinv train`")
    problem, overrides, spec = record["problem"], record["overrides"], record["network"]
    digest = record.get("model_sha256")
    bad = next(((field, value, expected) for field, value, expected, ok in (
        ("problem", problem, "the problem's name or module path (a non-empty str)",
         isinstance(problem, str) and problem.strip()),
        ("overrides", overrides, "an object of the problem's settings (name: value)",
         isinstance(overrides, dict)),
        ("network", spec, f"an object with 'kind' one of {', '.join(map(repr, NETWORKS))}",
         isinstance(spec, dict) and spec.get("kind") in NETWORKS),
        ("model_sha256", digest, "the sha256 of model.pt (a str of 64 hex digits)",
         digest is None or isinstance(digest, str)),
        ("record_sha256", record.get("record_sha256"),
         "the sha256 of its other fields (a str of 64 hex digits)",
         record.get("record_sha256") is None or isinstance(record.get("record_sha256"), str)),
        ("fingerprint", record.get("fingerprint"), "the problem's sizes and numbers written by pdeinv train",
         record.get("fingerprint") is None or _fingerprint_like(record["fingerprint"])),
        ("posterior_sha256", record.get("posterior_sha256"),
         "the sha256 of posterior.npz (a str of 64 hex digits), or null for a run without one",
         record.get("posterior_sha256") is None or isinstance(record.get("posterior_sha256"), str)),
    ) if not ok), None)
    if bad is not None:
        field, value, expected = bad
        text = json.dumps(value)
        text = text if len(text) <= 60 else text[:57] + "..."
        raise ValueError(f"{where}: {RUN_FILE}'s {field!r} is {text}; expected {expected} (an edited "
                         f"{RUN_FILE}? rerun `pdeinv train`)")
    return record


def _load_state(model, state, where: str) -> None:
    """Load ``state`` (strict) into ``model``; a state that does not fit is a ``ValueError`` naming the first
    trained tensor whose shape differs, with both shapes (buffers such as a folded whitening's resize as they
    load), else the first missing or unexpected name (no internal class names)."""
    from collections.abc import Mapping

    import torch

    if not isinstance(state, Mapping):
        raise ValueError(f"{where}: {MODEL_FILE} holds {type(state).__name__}, not a state dict of named "
                         "tensors; rerun `pdeinv train`")
    try:
        model.load_state_dict(state)
        return
    except Exception as err:  # noqa: BLE001  (torch's words differ by version: say it in ours)
        why = (str(err).strip().splitlines() or [type(err).__name__])[-1].strip()[:120]
    have = {k: tuple(v.shape) for k, v in state.items() if isinstance(v, torch.Tensor)}
    want = model.state_dict()
    lost, extra = [k for k in want if k not in state], [k for k in state if k not in want]
    shaped = [(k, tuple(v.shape)) for k, v in model.named_parameters() if k in have and have[k] != v.shape]
    shaped = shaped or [(k, tuple(v.shape)) for k, v in want.items()  # else a buffer (a fitted layer's)
                        if isinstance(v, torch.Tensor) and k in have and have[k] != tuple(v.shape)]
    if shaped:
        k, shape = shaped[0]
        why = f"{MODEL_FILE}'s {k!r} is {have[k]}, the network {RUN_FILE} describes has {shape}"
    elif lost or extra:
        why = (f"{MODEL_FILE} has no {lost[0]!r}, which the network {RUN_FILE} describes has" if lost else
               f"{MODEL_FILE}'s {extra[0]!r} is not in the network {RUN_FILE} describes")
    raise ValueError(f"{where}: {MODEL_FILE} does not fit its {RUN_FILE} ({why}): another problem or "
                     "settings?") from None


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _recorded_problem(run: Path, problem) -> None:
    """Refuse ``problem`` where ``run.json`` names another built-in problem or records other settings (the
    posterior of heat_1d at n=8 has the size of wave_1d's at n=8). A module path is not compared by name
    (its Problem's name is the module's choice); records that cannot be read are :func:`load_run`'s."""
    from ..problem.definition import find_module, import_module
    from ..problem.settings import resolve
    from ..problem.trained import differ

    try:
        record = json.loads((run / RUN_FILE).read_text())
        name, overrides = record["problem"], dict(record["overrides"])
    except (OSError, ValueError, KeyError, TypeError):
        return
    try:  # the settings the run was trained with: its module's defaults and the overrides it records
        trained = resolve(import_module(find_module(name)).SETTINGS, overrides, name)
    except Exception:  # noqa: BLE001  (a module without SETTINGS, moved or broken: only what was recorded)
        trained = overrides
    where = f"run folder {os.fspath(run)!r}"
    if isinstance(name, str) and not (name.endswith(".py") or "/" in name or os.sep in name) \
            and name != problem.name:
        raise ValueError(f"{where} is a run of problem {name!r}, not of {problem.name!r}; pass the run's "
                         "own problem (pdeinv.load_run(run_dir)[0])")
    for k, v in trained.items():
        if k in problem.settings and differ(problem.settings[k], v) and str(problem.settings[k]) != str(v):
            raise ValueError(f"{where} was trained with {k}={v}; the problem given has "
                             f"{k}={problem.settings[k]!r}: pass the run's own problem "
                             "(pdeinv.load_run(run_dir)[0])")


def _posterior_digest(run: Path, path: Path) -> str | None:
    """The sha256 ``run.json`` records for ``posterior.npz``, checked against what is there: a deleted
    posterior of a calibrated run (it silently dropped the error bars) and a posterior where the record
    says the run has none are refused. ``None`` for records without the field (earlier pdeinv versions),
    folders without ``run.json`` and runs without a posterior (nothing to compare the file's bytes with;
    :func:`load_posterior` compares them, after checking what the file holds)."""
    try:
        record = json.loads((run / RUN_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or "posterior_sha256" not in record:
        return None
    digest, where = record["posterior_sha256"], f"run folder {os.fspath(run)!r}"
    if digest is None and path.is_file():
        raise ValueError(f"{where}: its {RUN_FILE} records no posterior, but a {POSTERIOR_FILE} is there "
                         "(another run's?); remove it, or rerun `pdeinv train`")
    if digest is not None and not path.is_file():
        raise ValueError(f"{where}: its {POSTERIOR_FILE} is missing (the run was calibrated: its "
                         f"{RUN_FILE} records one); copy a run's files together, or rerun `pdeinv train`")
    return digest if isinstance(digest, str) else None


def _check_model_file(path: Path, digest, where: str) -> None:
    """``model.pt`` must be the file its ``run.json`` was written with (``model_sha256``; records of
    earlier pdeinv versions have none and are not checked): a model of the same shape copied from another
    run loads without a shape error and predicts another run's answers."""
    if digest is None:
        return
    if _sha256(path) != digest:
        raise ValueError(f"{where}: {MODEL_FILE} is not the model its {RUN_FILE} was written with (its "
                         "sha256 differs: another run's model, or an edited file); copy a run's files "
                         "together, or rerun `pdeinv train`")


def clear_outputs(out, keep=()) -> list[str]:
    """Remove the files of :data:`OUTPUTS` in ``out`` (not those in ``keep``) and their stale
    temporaries; other files stay. Returns the names removed."""
    out, removed = Path(out), []
    for name in OUTPUTS:
        if name in keep:
            continue
        remove_stale_temporaries(out / name)
        if (out / name).is_file():
            (out / name).unlink()
            removed.append(name)
    return removed


def existing_outputs(out) -> list[str]:
    """The files of :data:`OUTPUTS` present in ``out``."""
    return [name for name in OUTPUTS if (Path(out) / name).is_file()]
