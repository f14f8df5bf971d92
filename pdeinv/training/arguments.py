"""What the public entry points accept (``pdeinv.train``, ``Trainer``, ``export.predict``, ``save_run``,
``plots.plot_prediction``): each argument checked once, where it comes in.

A wrong *kind* of object is a ``TypeError`` and a wrong *value* a ``ValueError``; both name the
argument, the value and what is allowed, and, for the mix-ups users make (arguments swapped, the
``Result`` instead of its model, a class instead of an instance), the fix.
"""

from __future__ import annotations

import os
import sys

from .._checks import SEED_MAX, seed  # noqa: F401  (the seed= of every entry point: one check)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _named(name: str, value) -> str:
    """``name=value`` for small values, ``name`` alone where the repr would be a wall of numbers."""
    plain = not (_is_rule(value) or isinstance(value, type) or _is_array(value) or _is_result(value))
    return f"{name}={_short(value)}" if plain and "\n" not in repr(value) else name  # one line


def _kind(value) -> str:
    """What ``value`` is, in a user's words (for messages)."""
    from ..problem.definition import Problem

    if isinstance(value, Problem):
        return "a Problem"
    if _is_result(value):
        return "a training Result"
    if isinstance(value, type):
        return f"the class {value.__name__}"
    if _is_rule(value):
        return f"an update rule ({type(value).__name__})"
    if _is_array(value):
        return f"an array of shape {tuple(value.shape)}"
    torch = sys.modules.get("torch")
    if torch is not None and isinstance(value, torch.nn.Module):
        return f"a network ({type(value).__name__})"
    return type(value).__name__


def _is_rule(value) -> bool:
    from ..methods.protocol import Steps

    return not isinstance(value, type) and isinstance(value, Steps)


def _is_array(value) -> bool:
    """A numpy array or a torch tensor (torch looked up, not imported: no tensor exists before it is)."""
    import numpy as np

    torch = sys.modules.get("torch")
    return isinstance(value, np.ndarray) or (torch is not None and isinstance(value, torch.Tensor))


def _is_result(value) -> bool:
    """A :class:`pdeinv.training.trainer.Result` (looked up, not imported: the trainer imports this module,
    and no Result exists before it is imported)."""
    trainer = sys.modules.get(f"{__package__}.trainer")
    return trainer is not None and isinstance(value, trainer.Result)


def problem(value, where: str = "train"):
    """A :class:`~pdeinv.Problem`, or a problem name / module path loaded with :func:`pdeinv.load_problem`
    (``train("heat_1d", SIP())`` works)."""
    from ..problem.definition import Problem, load_problem

    if isinstance(value, Problem):
        return value
    if isinstance(value, (str, os.PathLike)):
        return load_problem(value)
    hint = ""
    if _is_rule(value) or isinstance(value, type):
        hint = f"; the arguments are {where}(problem, rule, model=None): swapped?"
    raise TypeError(f"{_named('problem', value)} is {_kind(value)}; expected a pdeinv.Problem "
                    f"(pdeinv.load_problem('heat_2d')) or a problem name such as 'heat_2d'{hint}")


def rule(value, problem_, model_=None):
    """An update rule, or a method name (``"sip"``, ``"gd"``, ``"adam"``, ``"hig"``, ``"supervised"``)
    built with its preset for ``model_`` (:func:`pdeinv.methods.presets.make_rule`, what ``pdeinv train
    --method`` builds; a network not linear in its parameters takes the paper's SIP optimizer)."""
    from ..methods.presets import METHODS, make_rule

    if isinstance(value, str):
        if value not in METHODS:
            raise ValueError(f"rule={value!r} is not a method name; expected one of "
                             f"{', '.join(map(repr, METHODS))} or an update rule such as pdeinv.SIP()")
        from ..nets.protocol import declared

        linear = model_ is None or declared(model_).linear_in_parameters() is not None
        return make_rule(value, problem_, linear_net=linear)[0]
    if isinstance(value, type) and _is_rule_class(value):
        raise TypeError(f"rule={value.__name__} is a class; expected an instance: pdeinv.{value.__name__}()")
    if _is_rule(value):
        return value
    from ..problem.definition import Problem

    swapped = isinstance(value, Problem)
    hint = "; the arguments are train(problem, rule, model=None): swapped?" if swapped else ""
    missing = [m for m in ("init", "update") if m not in dir(value)]
    raise TypeError(f"{_named('rule', value)} is {_kind(value)}; expected an update rule (pdeinv.SIP(), "
                    f"pdeinv.GD(), pdeinv.HIG(), ...: it has no {' or '.join(missing) or 'init/update'} "
                    f"method) or a method name such as 'sip'{hint}")


def _is_rule_class(cls: type) -> bool:
    from ..methods.protocol import Steps

    return issubclass(cls, Steps)


def model(value, name: str = "model", optional: bool = True):
    """A ``torch.nn.Module`` (``None`` where ``optional``); a ``Result`` or an array says what to pass."""
    import torch

    if value is None and optional:
        return None
    if isinstance(value, torch.nn.Module):
        if any(t.is_meta for t in (*value.parameters(), *value.buffers())):
            raise ValueError(f"{name} has tensors on the 'meta' device (shapes only, no values); expected a "
                             "network with its weights on the cpu or a cuda device (Trainer(device=...) "
                             "moves it)")
        low = {str(t.dtype) for t in value.parameters() if t.dtype in (torch.float16, torch.bfloat16)}
        if low:
            raise ValueError(f"{name} has {' and '.join(sorted(low))} parameters; expected torch.float32 or "
                             f"torch.float64 ({name}.float() or {name}.double()), as for dtype=")
        return value
    if _is_result(value):
        raise TypeError(f"{name} is a training Result; expected its network: pass result.model")
    hint = ""
    if _is_array(value):
        hint = "; arguments swapped? (the network comes first)" if name == "model" else ""
    raise TypeError(f"{_named(name, value)} is {_kind(value)}; expected a torch.nn.Module "
                    f"(problem.model(), or result.model of a finished run){hint}")


def stop(value, problem_, steps=None, model_=None):
    """A stopping rule (``init``/``check``, ``n_val``, ``every``), ``None``, or a name, as ``pdeinv train
    --stop`` builds it: ``"auto"`` (:func:`~pdeinv.training.stopping.chosen` for the run's ``steps`` and
    network ``model_``), ``"discrepancy"`` (:class:`~pdeinv.DiscrepancyStop`), ``"plateau"``
    (:class:`~pdeinv.PlateauStop`, checked about 30 times in ``steps``) or ``"none"``."""
    if value is None:
        return None
    if isinstance(value, str):
        from .stopping import DiscrepancyStop, PlateauStop, chosen

        names = {"auto": lambda: chosen(problem_, steps, model_),
                 "discrepancy": lambda: DiscrepancyStop(noise=None if problem_.noise else "estimate"),
                 "plateau": lambda: PlateauStop(every=max(1, (steps or 30) // 30)), "none": lambda: None}
        if value not in names:
            raise ValueError(f"stop={value!r} is not allowed; expected one of {', '.join(map(repr, names))}, "
                             "None or a stopping rule such as pdeinv.DiscrepancyStop()")
        return names[value]()
    from .stopping import StopRule

    missing = [m for m in ("init", "check", "n_val", "every") if m not in dir(value)]
    if isinstance(value, type) or not isinstance(value, StopRule):
        what = f"a class: call it, {value.__name__}()" if isinstance(value, type) else \
            f"{_kind(value)} without {', '.join(missing)}"
        raise TypeError(f"stop={_short(value)} is {what}; expected a stopping rule such as "
                        "pdeinv.DiscrepancyStop(), 'discrepancy' or None")
    return value


def checkpoint(value):
    """A :class:`~pdeinv.Checkpoint`, ``None``, or a path (``Checkpoint(path)``, its default ``every``)."""
    if value is None:
        return None
    if isinstance(value, (str, os.PathLike)):
        from .checkpoint import Checkpoint

        if not os.fspath(value).strip():
            raise ValueError("checkpoint='' is empty; expected a path or pdeinv.Checkpoint(path, every=k)")
        return Checkpoint(value)
    from .checkpoint import Checkpointing

    if not isinstance(value, Checkpointing):
        raise TypeError(f"checkpoint={_short(value)} is {_kind(value)}; expected pdeinv.Checkpoint(path, "
                        "every=k) or a path")
    return value


def callbacks(value) -> list:
    """A list of ``callback(record, model)``; one callable alone is a list of one."""
    if callable(value):
        return [value]
    try:
        items = list(value)
    except TypeError:
        raise TypeError(f"callbacks={_short(value)} is {_kind(value)}; expected a list of functions "
                        "callback(record, model) -> bool | None") from None
    bad = [i for i, c in enumerate(items) if not callable(c)]
    if bad:
        raise TypeError(f"callbacks[{bad[0]}]={_short(items[bad[0]])} is not callable; expected functions "
                        "callback(record, model) -> bool | None")
    return items


def flag(value, name: str, optional: bool = False):
    """``True``/``False`` (``None`` where ``optional``)."""
    if (value is None and optional) or isinstance(value, bool):
        return value
    allowed = "True, False or None" if optional else "True or False"
    raise TypeError(f"{name}={_short(value)} is {_kind(value)}; expected {allowed}")


def dtype(value):
    """``torch.float32``, ``torch.float64`` or ``None``: the networks' whitening and least-squares steps
    (eigh, Cholesky) have no half-precision kernels, and fields below float32 lose the physics' scales."""
    import torch

    if value is None or value in (torch.float32, torch.float64):
        return value
    raise TypeError(f"dtype={_short(value)} is not allowed; expected None, torch.float32 or torch.float64")


def parallel(value):
    """``parallel=``: :class:`~pdeinv.training.distributed.Single` or ``DataParallel`` (from torchrun's
    environment: :func:`pdeinv.training.distributed.from_env`)."""
    from .distributed import DataParallel, Single

    if not isinstance(value, (Single, DataParallel)):
        raise TypeError(f"parallel={_short(value)} is {_kind(value)}; expected pdeinv.training.distributed."
                        "Single() or DataParallel (pdeinv.training.distributed.from_env() under torchrun)")
    return value


def fits(model, problem, name: str = "model"):
    """``model`` takes the problem's observations: two zero rows of width ``problem.operator.n_out`` go
    through it (in eval mode), and must give ``problem.N`` unknowns each."""
    import torch

    if model is None:
        return model
    param = next(iter(model.parameters()), None)
    dtype = param.dtype if param is not None else torch.float32
    m = problem.operator.n_out
    was = model.training
    model.eval()  # no running statistics updated, no dropout: the check leaves the model as it was
    try:
        with torch.no_grad():
            out = model(torch.zeros(2, m, dtype=dtype, device=None if param is None else param.device))
    except RuntimeError as err:  # a shape the layers refuse; anything else (an unfitted input transform)
        first = (str(err).strip().splitlines() or [""])[0][:100]  # is for the trainer to meet later
        if "shape" not in first and "size" not in first:
            return model
        raise ValueError(f"{name} does not take this problem's {m} observations per row ({first}); "
                         f"expected a network from {m} observations to {problem.N} unknowns, e.g. "
                         "problem.model()") from None
    finally:
        model.train(was)
    if tuple(out.shape) != (2, problem.N):
        raise ValueError(f"{name} maps {m} observations to shape {tuple(out.shape)[1:]}; expected "
                         f"{problem.N} unknowns per row (problem.N)")
    return model


def target(value):
    """``target=``: ``"auto"`` (the rule's default target), ``None`` (the observations themselves) or a
    target strategy (``fit(problem, y, noise, model=, fields=)``: :mod:`pdeinv.methods.targets`)."""
    if value is None or (isinstance(value, str) and value == "auto"):
        return value
    allowed = "'auto', None or a target strategy such as pdeinv.methods.targets.SpectralWiener()"
    if isinstance(value, str):
        raise ValueError(f"target={value!r} is not allowed; expected {allowed}")
    if isinstance(value, type) or "fit" not in dir(value):
        what = f"a class: call it, {value.__name__}()" if isinstance(value, type) else \
            f"{_kind(value)} without fit"
        raise TypeError(f"target={_short(value)} is {what}; expected {allowed}")
    return value


def prior(value):
    """``prior=``: ``"auto"`` (the default :class:`~pdeinv.training.plan.PriorStage`), ``None`` (no prior
    stage) or a stage object."""
    from .plan import PriorStage

    if isinstance(value, str) and value == "auto":
        return PriorStage()
    if value is not None and not isinstance(value, PriorStage):
        raise TypeError(f"prior={_short(value)} is {_kind(value)}; expected 'auto', None or a "
                        "pdeinv.PriorStage")
    return value
