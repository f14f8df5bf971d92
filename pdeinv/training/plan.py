"""What a run will do, decided before anything is built: :func:`plan` and :meth:`Plan.explain`.

One chooser for ``pdeinv train`` and Python alike (lineax's ``AutoLinearSolver`` is the model: a chooser
you can ask). It reads what the problem already decided (the operator's backend and why,
:meth:`pdeinv.physics.propagator.Propagator.compile`; the local inverse), the rule's preset
(:mod:`pdeinv.methods.presets`), which network the problem gets (:mod:`pdeinv.nets.defaults`) and the
stages with their counts (:mod:`pdeinv.training.stages`), and prices that same plan in memory
(:func:`pdeinv.training.budget.run_bytes`, the guard's own estimate).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..util.memory import GB
from .stages import NEGLIGIBLE, PILOT
from .trainset import N_TRAIN


@dataclass(frozen=True)
class Plan:
    """A run's decisions and their reasons (:func:`plan`); :meth:`explain` prints them."""

    problem: dict
    rule: dict
    network: dict
    stages: list[dict]
    memory: dict = field(default_factory=dict)

    def explain(self) -> str:
        p, r, net = self.problem, self.rule, self.network
        lines = [f"problem   {p['name']}: {p['unknowns']} unknowns, {p['observations']} observations, "
                 f"{'linear' if p['linear'] else 'nonlinear'} physics, noise {p['noise']:g}",
                 f"backend   {p['backend']}",
                 f"inverse   {p['inverse']}",
                 f"rule      {r['name']}: {r['steps']} steps of {r['batch']} rows on {r['n_train']} training "
                 f"observations ({', '.join(f'{k}={v}' for k, v in r['settings'].items())})",
                 f"network   {net['kind']}: {net['params']:,} trained parameters, {net['buffers']:,} fixed "
                 f"numbers ({net['why']})"]
        for i, st in enumerate(self.stages, 1):
            lines.append(f"stage {i}   {_stage_text(st)}")
        if self.memory:
            total = sum(self.memory.values())
            ranked = sorted(self.memory.items(), key=lambda kv: -kv[1])
            parts = ", ".join(f"{k} {v / GB:.3g}" for k, v in ranked)
            lines.append(f"memory    {total / GB:.3g} GB at the peak ({parts})")
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return {"problem": self.problem, "rule": self.rule, "network": self.network, "stages": self.stages,
                "memory_bytes": self.memory}


def _stage_text(st: dict) -> str:
    if st["name"] == "prior":
        if st.get("skipped"):
            return f"prior: none ({st['skipped']})"
        dc = ("then the data-consistency layer (P f(y) = y to the noise)" if st["consistency"]
              else "no data-consistency layer (the operator has no spectral basis)")
        return (f"prior: unless the rule's estimate is within {NEGLIGIBLE:g} of {PILOT} pilot draws, "
                f"{st['correction']} fitted on {st['draws']} prior draws ({st['prior']}), at most "
                f"{st['max_steps']} steps of {st['batch']}, kept only if it lowers the held-out error; {dc}")
    return f"{st['name']}: the rule trains the network through the physics ({st['steps']} steps)"


def plan(problem, rule: str = "sip", *, net: str = "default", hidden=None, prior="auto",
         n_train: int = N_TRAIN, steps: int | None = None, batch_size: int | None = None, own=None,
         n_test: int = 128,
         **settings) -> Plan:
    """The plan of ``Trainer(problem, rule, ...)`` / ``pdeinv train`` with these arguments (``problem`` a
    :class:`~pdeinv.Problem`, a name or a module path; ``rule`` a method name; ``settings`` the rule's, as
    :func:`pdeinv.methods.presets.make_rule` takes them; ``own``: a
    :class:`pdeinv.training.data.OwnData`, the user's rows). Builds nothing but the problem and the
    rule."""
    from ..methods.presets import make_rule, run_defaults
    from ..nets import network_size
    from ..nets.defaults import correction_kind
    from ..physics.nonlinear import is_linear
    from ..problem import Problem, load_problem
    from .budget import run_bytes
    from .stages import PriorStage

    if not isinstance(problem, Problem):  # a name or a module path, as Trainer takes it
        problem = load_problem(problem)
    if isinstance(prior, str) and prior == "auto":
        prior = PriorStage()
    rule_obj, hp = make_rule(rule, problem, problem.noise, hidden=hidden, **settings)
    preset = run_defaults(rule_obj, None, problem)
    steps = steps if steps is not None else hp.get("steps") or preset["steps"]
    batch = batch_size or hp.get("batch_size") or n_train
    kind = "mlp" if hidden else net
    size = network_size(problem, kind, hidden)
    op = problem.operator
    info = {"name": problem.name, "unknowns": problem.N, "observations": op.n_out, "linear": is_linear(op),
            "noise": float(problem.noise or 0.0),
            "backend": getattr(op, "choice", None) or type(op).__name__,
            "inverse": repr(problem.inverse_simulator)}
    stages = [{"name": rule_obj.name, "steps": steps, "batch": batch}]
    refined = kind == "default" and problem.model_factory is None and correction_kind(problem) is not None
    prior_draws = 0
    if refined and prior is not None:
        st = prior.planned(problem, correction_kind(problem), own)
        stages.append(st)
        prior_draws = 0 if st.get("skipped") else st["draws"]
    memory = run_bytes(problem, n_train, n_test, batch, hidden, kind if kind != "mlp" else "default",
                       rule, 128, prior_draws, hp.get("optimizer") or "adam")
    why = ("the MLP of --hidden" if hidden else
           "the problem's default: a linear estimate trained by the rule" + (
               ", plus a nonlinear correction and a data-consistency layer for the prior stage" if refined
               else ""))
    return Plan(info, {"name": rule_obj.name, "steps": steps, "batch": batch, "n_train": n_train,
                       "settings": {k: v for k, v in hp.items() if v is not None and k not in ("steps",)}},
                {"kind": kind, "params": int(size["params"]), "buffers": int(size["buffers"]), "why": why},
                stages, memory)
