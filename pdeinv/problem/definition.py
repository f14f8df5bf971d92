"""``Problem``: one inverse-problem scene, and ``load_problem`` to get one by name or path.

Contract (docs/design.md): ``points`` ``(dim, N)``; ``operator.forward/adjoint``
(numpy ``(B, N)``); ``inverse(y, x0)``; ``sample(n, seed) -> (x, y)``; ``model()``.
"""

from __future__ import annotations

import importlib.util
import inspect
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from .._checks import batch, count, nonnegative
from .._checks import seed as _seed
from ..fem.forms import Discretization
from ..physics.base import LinearOperator
from ..physics.nonlinear import Physics, is_linear
from ..physics.propagator import chosen
from ..util.memory import check
from .sampling import add_noise

#: the package that holds the built-in problems (the repository's ``problems/``, installed as
#: ``pdeinv.problems`` with its meshes; see ``pyproject.toml``)
BUILTIN_PACKAGE = "pdeinv.problems"


#: the magnitudes a scene's sampler and operator may return: a network trains on them in float32, whose
#: squares of a batch stay finite within (pdeinv.problem.units.AS_IS, the window own data is rescaled into)
DRAWS_AS_IS = (1e-12, 1e12)


@dataclass
class Problem:
    """A scene: discretization, forward operator, data distribution, defaults.

    ``sampler(n, rng) -> (n, N)`` draws true initial fields; observations are
    ``y = P x`` plus relative Gaussian noise of level ``noise`` (see
    :func:`pdeinv.problem.sampling.add_noise`). A time-stepping operator no one chose a backend for
    (``Heat(...).sensors(S, k)``, ``Wave(...)``) is compiled by ``auto`` here, in the norms of
    ``disc.M`` (:func:`pdeinv.physics.propagator.chosen`): no user has to call ``.compile``.
    """

    name: str
    disc: Discretization
    operator: LinearOperator
    sampler: Callable[[int, np.random.Generator], np.ndarray]
    settings: dict = field(default_factory=dict)
    noise: float = 0.0
    inverse_simulator: Callable | None = None
    model_factory: Callable | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip() or not self.name.isprintable() \
                or len(self.name) > NAME_CHARS:  # runs, files and one-line messages name it
            raise ValueError(f"Problem(name={self.name!r:.80}) is not allowed; expected a non-empty string "
                             f"of at most {NAME_CHARS} printable characters")
        self.name = str(self.name)  # np.str_('heat'): a plain string in run.json
        if not isinstance(self.operator, Physics):
            raise TypeError(f"operator={type(self.operator).__name__} is not allowed; expected a "
                            "pdeinv.physics.LinearOperator (e.g. pdeinv.physics.Matrix(A) or Heat(...)) or "
                            "a nonlinear pdeinv.physics.Physics (with jvp and vjp): they declare what the "
                            "rules may use")
        # an operator built by hand goes through the backend chooser as the scenes' do; a nonlinear
        # one (declared linear=False) has no matrix to compile
        nodes = None if self.disc is None else np.shape(self.disc.points)[-1]
        if nodes is not None and nodes != self.operator.n_in:
            raise ValueError(f"problem {self.name!r}: its mesh has {nodes} unknowns but its operator takes "
                             f"{self.operator.n_in}; expected the operator of this mesh")
        if self.sampler is not None and not callable(self.sampler):
            raise TypeError(f"sampler={self.sampler!r:.60} is {type(self.sampler).__name__}; expected a "
                            "function sampler(n, rng) -> (n, N) array of true fields, or None (no prior)")
        # load_problem's check of the setting, and its words; None: noise-free, as it always was read
        self.noise = 0.0 if self.noise is None else nonnegative(self.noise, "noise")
        if is_linear(self.operator):
            chosen(self.operator, None if self.disc is None else self.disc.M)

    @property
    def points(self) -> np.ndarray:
        return self.disc.points

    @property
    def N(self) -> int:
        return self.operator.n_in

    def sample(self, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``(x, y)`` with ``x`` from the sampler and ``y = P x`` (+ noise); seeded."""
        n = count(n, "n")
        rng = np.random.default_rng(_seed(seed))
        check(8 * n * (self.N + self.operator.n_out), f"problem {self.name!r}: sample(n={n}) (x ({n}, "
              f"{self.N}) and y ({n}, {self.operator.n_out}) in float64)", "draw fewer rows, in chunks")
        x = self.draws(n, rng)
        y = self.operator.forward(x)
        if not np.isfinite(y).all():  # finite fields in, so the physics made them
            raise ValueError(f"problem {self.name!r}: its operator returned {int((~np.isfinite(y)).sum())} "
                             f"NaN/Inf observations of finite fields; expected finite P x (check its physics "
                             "and settings)")
        top = float(np.max(np.abs(y))) if y.size else 0.0
        if top > DRAWS_AS_IS[1] or 0 < top < DRAWS_AS_IS[0]:  # the network's float32 holds neither
            raise ValueError(f"problem {self.name!r}: its operator returned observations up to {top:.3g} of "
                             f"fields up to {float(np.max(np.abs(x))):.3g}; expected magnitudes between "
                             f"{DRAWS_AS_IS[0]:g} and {DRAWS_AS_IS[1]:g} ("
                             + ("rescale its operator)" if top > 1 else "the physics leaves nothing to "
                                "observe: settings such as a smaller κ or T, or rescale its operator)"))
        return x, add_noise(y, self.noise, rng)

    def draws(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` fields from the sampler, checked: shape ``(n, N)``, finite (a ``ValueError`` naming the
        problem otherwise)."""
        numerics = np.geterr()
        try:
            x = self.sampler(n, rng)
        except KeyboardInterrupt:
            raise
        except BaseException as err:  # a user's sampler: one line, file and line; pdeinv's own stand
            raise _sampler_failure(self.name, err) or _signature(self.name, self.sampler, err) or err
        finally:  # np.seterr(all="raise") inside it: pdeinv's solvers keep numpy's defaults
            np.seterr(**numerics)
        x = _as_array(self.name, x, (n, self.N))
        shape = np.shape(x)
        if shape != (n, self.N):
            raise ValueError(f"problem {self.name!r}: its sampler returned shape {shape} for {n} draws; "
                             f"expected ({n}, {self.N}), one row of the {self.N} unknowns per draw")
        x = x if x.dtype == np.float64 else x.astype(np.float64)  # ints, float32: the physics' float64
        if not np.isfinite(x).all():
            bad = int((~np.isfinite(x)).sum())
            raise ValueError(f"problem {self.name!r}: its sampler returned {bad} NaN/Inf values; expected "
                             "finite fields")
        top = float(np.max(np.abs(x))) if x.size else 0.0
        if top > DRAWS_AS_IS[1] or 0 < top < DRAWS_AS_IS[0]:
            raise ValueError(f"problem {self.name!r}: its sampler returned values up to {top:.3g}; expected "
                             f"magnitudes between {DRAWS_AS_IS[0]:g} and {DRAWS_AS_IS[1]:g} (the scene's own "
                             "units: rescale its sampler)")
        return x

    def inverse(self, y, x0) -> np.ndarray:
        """Local inverse simulator ``P⁻¹_(x0, P x0)(y)``; returns ``x0`` when ``y = P x0``."""
        if self.inverse_simulator is None:
            raise NotImplementedError(f"problem {self.name!r} has no inverse simulator")
        return self.inverse_simulator(y, x0)

    def model(self, **settings):
        """A fresh default network ``y -> x`` (torch.nn.Module): the problem's ``model_factory``, else
        :func:`pdeinv.nets.default_model` with ``settings`` (e.g. ``rows_per_component=8``, what
        ``--method gd`` and ``adam`` train; a ``model_factory`` takes no settings)."""
        if self.model_factory is not None:
            if settings:
                raise ValueError(f"this problem builds its network with its own model_factory, which "
                                 f"takes no settings; got {', '.join(sorted(settings))}")
            return self.model_factory(self)
        from ..nets import default_model

        return default_model(self, **settings)

    def relative_error(self, xhat, x) -> np.ndarray:
        """Relative L²(Ω) error per sample, ``‖x̂ − x‖_M / ‖x‖_M``."""
        xhat, _ = batch(xhat, self.N, "xhat")
        x, _ = batch(x, self.N, "x")
        if len(xhat) != len(x) and 1 not in (len(xhat), len(x)):
            raise ValueError(f"xhat has shape {xhat.shape} but x has {x.shape}; expected one estimate per "
                             "true field (the same shape), or one row against many")
        return self.disc.relative_error(xhat, x)

    def __repr__(self):
        return f"Problem({self.name!r}, N={self.N}, operator={self.operator!r})"


def builtin_dir() -> Path:
    """The folder of the built-in problem modules, found through the installed package."""
    return Path(os.fspath(resources.files(BUILTIN_PACKAGE)))


def _problem_dirs(cwd: bool = True) -> list[Path]:
    """Where ``load_problem('name')`` looks, in order: the folders in ``PDEINV_PROBLEMS``
    (``os.pathsep``-separated), ``./problems``, the built-ins, then the current folder (after the
    built-ins: a stray ``heat_2d.py`` there does not shadow the scene)."""
    extra = [Path(p) for p in os.environ.get("PDEINV_PROBLEMS", "").split(os.pathsep) if p]
    return extra + [Path.cwd() / "problems", builtin_dir()] + ([Path.cwd()] if cwd else [])


def available() -> list[str]:
    """Names of the problem modules in the problem folders (the current folder's modules are found by
    name too, but not listed: it holds other Python files)."""
    names = set()
    for d in _problem_dirs(cwd=False):
        if d.is_dir():
            names |= {p.stem for p in d.glob("*.py") if not p.stem.startswith("_")}
    return sorted(names)


def find_module(name_or_path: str | os.PathLike) -> Path:
    """The module file of a problem name (searched as in :func:`load_problem`) or path."""
    spec = os.fspath(name_or_path)
    if spec.endswith(".py") or os.sep in spec or "/" in spec:
        path = Path(spec)
        try:
            path.stat()
        except OSError as err:  # too long a name, no permission: said before any is_file() raises it
            if not isinstance(err, (FileNotFoundError, NotADirectoryError)):
                shown = spec if len(spec) <= 80 else spec[:77] + "..."
                raise ValueError(f"problem module {shown!r} cannot be looked up ({err.strerror}); expected "
                                 "the path of a readable .py file, or a problem name") from None
        if path.is_dir():
            raise ValueError(f"problem module {spec!r} is a directory; expected a .py file with "
                             "make(**overrides), or a problem name")
        if path.exists() and not path.is_file():
            raise ValueError(f"problem module {spec!r} is not a regular file (a device, a pipe or a socket); "
                             "expected a .py file with make(**overrides), or a problem name")
        if not path.is_file():
            names = ", ".join(available()[:4])
            raise ProblemNotFoundError(f"problem module {spec!r} does not exist; expected the path of a .py "
                                       f"file with make(**overrides), or a problem name ({names}, ...: "
                                       "pdeinv.available())")
        if path.suffix != ".py":
            raise ValueError(f"problem module {spec!r} is not a .py file; expected a Python module "
                             "with make(**overrides), or a problem name")
    else:
        if len(spec) > NAME_CHARS:  # no file of that name can exist: the file system's 255 bytes
            raise ValueError(f"unknown problem {spec[:40] + '...'!r} ({len(spec)} characters); a problem "
                             f"name has at most {NAME_CHARS}: a built-in ({', '.join(available()[:4])}, "
                             "...), a module's name or the path of a module file")
        found = [d / f"{spec}.py" for d in _problem_dirs() if (d / f"{spec}.py").is_file()]
        if not found:
            raise ValueError(f"unknown problem {spec!r}; available: {', '.join(available())} "
                             "(or give the path of a module file)")
        path = found[0]
    return path


def _as_array(name: str, x, shape: tuple) -> np.ndarray:
    """What a sampler returned as a real array: a list or a torch tensor converted, anything else (None,
    text, complex numbers) a ``ValueError`` naming the problem and what was expected."""
    expected = (f"expected a numpy array of shape {shape}, one row of the {shape[1]} unknowns per draw")
    what = type(x).__name__
    if not isinstance(x, np.ndarray):
        try:
            x = np.asarray(x, dtype=float)  # a CPU tensor without grad converts; others say what they are
        except (TypeError, ValueError, RuntimeError):
            x = None
        if x is None or x.ndim == 0:
            raise ValueError(f"problem {name!r}: its sampler returned {what}; {expected}")
    elif not np.issubdtype(x.dtype, np.number) or np.issubdtype(x.dtype, np.complexfloating):
        raise ValueError(f"problem {name!r}: its sampler returned an array of {x.dtype}; {expected} of real "
                         "numbers")
    return x


def _signature(name: str, sampler, err: Exception) -> ValueError | None:
    """A ``ValueError`` naming ``sampler`` where ``err`` is the ``TypeError`` of calling it as
    ``sampler(n, rng)`` (raised by the call itself: its traceback ends in this file), else None."""
    import traceback

    frames = traceback.extract_tb(err.__traceback__)
    here = Path(__file__).resolve()
    if not isinstance(err, TypeError) or not frames or Path(frames[-1].filename).resolve() != here:
        return None
    try:
        line = inspect.getsourcelines(sampler)[1]
        where = f"{sampler.__qualname__} ({inspect.getsourcefile(sampler)}, line {line})"
    except (AttributeError, TypeError, OSError):  # a callable object, a builtin: its type
        where = type(sampler).__name__
    return ValueError(f"problem {name!r}: its sampler {where} cannot be called as sampler(n, rng): "
                      f"{first_line(err)}; expected a function of the draw count and a numpy Generator")


def _sampler_failure(name: str, err: BaseException) -> ValueError | None:
    """``err`` raised in a user's sampler (its innermost frame outside pdeinv) as one line naming the
    sampler's file and line, or None (pdeinv's own error, whose message stands)."""
    import traceback

    frames = traceback.extract_tb(err.__traceback__)
    package = Path(__file__).resolve().parent.parent
    if not frames or Path(frames[-1].filename).resolve().is_relative_to(package):
        return None
    mine = [f for f in frames if not Path(f.filename).resolve().is_relative_to(package)]
    where = f"{mine[-1].filename}, line {mine[-1].lineno}, in {mine[-1].name}"
    text = first_line(err)
    what = f"{type(err).__name__}" + (f": {text}" if text else "")
    if isinstance(err, SystemExit):
        what = f"called sys.exit({err.code!r}); expected the sampler to return the fields"
    error = ValueError(f"{where}: {what} (the sampler of problem {name!r})")
    error.__cause__ = err
    return error


class ProblemNotFoundError(FileNotFoundError, ValueError):
    """A problem module path that names no file: a ``FileNotFoundError`` and, as every bad argument of
    pdeinv's, a ``ValueError``."""


class ProblemModuleError(ValueError):
    """A user's problem module that cannot be imported, whose ``make`` raises or exits, or that returns no
    :class:`Problem`. The message is one line: the module's file, the line that failed (the innermost in
    the module's own file, or the syntax error's) and the exception's type and message; ``__cause__`` is
    the exception itself (the CLI prints its traceback with ``-v``)."""


def _failure(path: Path, err: BaseException, where: str) -> ProblemModuleError:
    """``err`` raised while importing ``path`` or calling its ``make``, as one line naming file and line."""
    import traceback

    mine = [f for f in traceback.extract_tb(err.__traceback__) if Path(f.filename) == path]
    line = f", line {mine[-1].lineno}, in {mine[-1].name}" if mine else ""
    if isinstance(err, SyntaxError):  # its own file and line (the module's, or a helper it imports)
        other = "" if not err.filename or Path(err.filename) == path else f" in {err.filename!r}"
        line = f", line {err.lineno}" if not other and err.lineno else line
        what = f"SyntaxError{other}: {err.msg}" + (f" (line {err.lineno})" if other and err.lineno else "")
    elif isinstance(err, SystemExit):
        what = f"called sys.exit({err.code!r}); expected make(**overrides) to return a pdeinv.Problem"
    else:
        text = first_line(err)
        what = f"{type(err).__name__}: {text}" if text else type(err).__name__
    return ProblemModuleError(f"problem module {where}{line}: {what}")


def first_line(err: BaseException, n: int = 300) -> str:
    """The first line of ``err``'s message (at most ``n`` characters); ``'(its message cannot be
    printed: …)'`` when its ``__str__`` raises (a user's exception class)."""
    try:
        text = str(err)
    except Exception as inner:  # noqa: BLE001  any failure of a user's __str__
        return f"(its message cannot be printed: {type(inner).__name__})"
    return (text.strip().splitlines() or [""])[0][:n]


def _pdeinvs_own(path: Path, err: Exception) -> bool:
    """Whether ``err`` is one of pdeinv's own one-line errors (a setting refused, a mesh file missing, a
    numerical failure) raised in pdeinv's code that the module's ``make`` called: its message stands."""
    import traceback

    from ..errors import numerical_types

    package, loader = Path(__file__).resolve().parent.parent, Path(__file__).resolve()
    for frame in reversed(traceback.extract_tb(err.__traceback__)):
        here = Path(frame.filename)
        if here == path or here == loader:  # the module's own code, or its import (a null byte: ValueError)
            return False
        if here.is_relative_to(package):
            return isinstance(err, (ValueError, FileNotFoundError, NotImplementedError, MemoryError,
                                    *numerical_types()))
    return False


def import_module(path: Path):
    """The user's or built-in problem module at ``path``, executed (its exceptions propagate) under the name
    :data:`~pdeinv.util.critical.USER_MODULE_PREFIX` + its stem, which keeps Ctrl-C and SIGTERM working
    while its own code runs (:mod:`pdeinv.cli.signals`)."""
    from ..util.critical import USER_MODULE_PREFIX

    spec = importlib.util.spec_from_file_location(f"{USER_MODULE_PREFIX}{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    kept, sys.dont_write_bytecode = sys.dont_write_bytecode, True  # no __pycache__ in the user's folder
    try:
        spec.loader.exec_module(module)
    finally:
        sys.dont_write_bytecode = kept
    return module


#: the longest problem name: it names files (``<name>.py``) within the file system's 255 bytes
NAME_CHARS = 200

#: the modules whose change of numpy's error handling was undone and said (once per module)
_RESTORED: set = set()


def _run_module(path: Path, overrides: dict, where: str) -> Problem:
    """Import the module at ``path`` and call its ``make(**overrides)``. A user's module that fails is a
    :class:`ProblemModuleError` in one line; a built-in's failure keeps its own exception (a bug)."""
    builtin = path.parent == builtin_dir().resolve()
    numerics, depth = np.geterr(), sys.getrecursionlimit()
    try:
        module = import_module(path)
        make = getattr(module, "make", None)
        if not callable(make):
            raise ProblemModuleError(f"problem module {where} has no function make(**overrides)")
        problem = make(**overrides)
    except KeyboardInterrupt:  # Ctrl-C, the module's or the user's: as everywhere else
        raise
    except BaseException as err:  # SystemExit, and a module's own BaseException subclasses
        if builtin or isinstance(err, ProblemModuleError) or (
                isinstance(err, Exception) and _pdeinvs_own(path, err)):
            raise
        raise _failure(path, err, where) from err
    finally:  # np.seterr(all="raise") made the solvers' underflows errors; a low recursion limit, torch's
        changed = [what for what, moved in (("numpy's floating-point error handling (np.seterr)",
                                              np.geterr() != numerics),
                                             ("Python's recursion limit", sys.getrecursionlimit() != depth))
                   if moved]
        np.seterr(**numerics)
        sys.setrecursionlimit(depth)
    if changed and path not in _RESTORED:
        import warnings

        _RESTORED.add(path)
        warnings.warn(f"problem module {where} changed {' and '.join(changed)}; pdeinv restored it: its "
                      "solvers rely on the defaults", RuntimeWarning, stacklevel=3)
    if not isinstance(problem, Problem):
        if inspect.iscoroutine(problem) or inspect.isgenerator(problem):  # never run: no "never awaited"
            problem.close()
        raise ProblemModuleError(f"problem module {where}: make() returned {type(problem).__name__}; "
                                 "expected a pdeinv.Problem" + (" (make must be a plain function, not "
                                 "async)" if inspect.iscoroutine(problem) else ""))
    ignored = [k for k, v in overrides.items() if k in problem.settings and _differs(problem.settings[k], v)]
    if ignored and not builtin:  # a run would record the override and train on the module's own value
        k = ignored[0]
        raise ProblemModuleError(f"problem module {where}: make({k}={overrides[k]!r}) returned a Problem "
                                 f"whose settings have {k}={problem.settings[k]!r}: make ignores the "
                                 "override (pass them to settings.resolve(SETTINGS, overrides, name))")
    return problem


def _differs(value, override) -> bool:
    """Whether a Problem's numeric setting is not the number it was given (``--set n=8``: the string '8');
    settings that are not numbers (names, paths, flags) are not compared."""
    try:
        return float(value) != float(override) and not isinstance(value, bool)
    except (TypeError, ValueError):
        return False


def load_problem(name_or_path: str | os.PathLike, **overrides) -> Problem:
    """Import ``problems/<name>.py`` (or a module file by path) and call ``make(**overrides)``.

    ``name_or_path``: a built-in or user problem name (:func:`available` lists them; looked up as
    :func:`find_module` says) or the path of a module file with ``make(**overrides)``; ``overrides``
    are the problem's settings (``pdeinv problems`` lists them), strings coerced. A user's module that
    cannot be imported, whose ``make`` raises or calls ``sys.exit``, or that returns no :class:`Problem`
    raises :class:`ProblemModuleError` (a ``ValueError``), one line naming its file and line; pdeinv's own
    errors raised inside ``make`` (a setting refused, a mesh file missing) keep their message.
    """
    if isinstance(name_or_path, Problem):
        raise TypeError(f"name_or_path is already a Problem ({name_or_path.name!r}); use it as it is, or "
                        f"load_problem({name_or_path.name!r}, **overrides) for other settings")
    expected = (f"expected a problem name (str: {', '.join(map(repr, available()[:4]))}, ...; "
                "pdeinv.available() lists them) or the path of a module file with make(**overrides)")
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise TypeError(f"name_or_path={name_or_path!r} is not allowed; {expected}")
    if not os.fspath(name_or_path).strip():
        raise ValueError(f"name_or_path={name_or_path!r} is empty; {expected}")
    path = find_module(name_or_path).resolve()
    spec = os.fspath(name_or_path)
    by_name = not (spec.endswith(".py") or os.sep in spec or "/" in spec)
    where = repr(str(path)) + (" (found by name in the current folder)"
                               if by_name and path.parent == Path.cwd().resolve() else "")
    folder = str(path.parent)
    if folder not in sys.path and path.parent != builtin_dir().resolve():
        # a user's module: its siblings import as a script's do (a helper next to the module)
        sys.path.insert(0, folder)
    return _run_module(path, overrides, where)
