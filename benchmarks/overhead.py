"""The trainer's overhead per step over a plain torch loop: same network, data, physics and Adam.

    OMP_NUM_THREADS=1 python benchmarks/overhead.py [--problem heat_2d] [--steps 200] [--repeats 5]

Both sides train ``--method adam``'s network (the CLI's default network with the preset's
``rows_per_component``) on the same 1024 training observations in the same batch order
(``seed_stream(0, TRAIN_DATA)``, ``seed_stream(0, BATCH_ORDER)``), with the input whitening fitted
the same way, through the same differentiable physics (:func:`pdeinv.apply`) and Adam at lr 1e-3:

* **trainer**: ``pdeinv.Trainer(problem, GD(adam, normalize=False), model)``: the guard (finite and
  loss-growth checks, the last good state, the step-size multiplier), batching, history and callbacks;
* **plain**: ``opt.zero_grad(); y_loss(apply(P, model(y)), y).backward(); opt.step()``.

A step's time is the median interval between consecutive steps 10 … steps−1 (no evaluation among
them: ``eval_every`` is past the last step; the median shrugs off a shared machine's pauses); the two
sides alternate, one thread, ``--repeats`` times, and the medians are compared.
Prints both and the ratio ``trainer / plain`` (issue 24 item 5: at most 1.05).

Measured on heat_2d (Adam, batch 32; the default network: a 961 × 961 float64 map after the whitening,
924 k parameters), one thread, on the 2-core machine shared with another engineer's jobs (load 2-3,
so absolute times drift between runs; each ratio is from interleaved runs of one invocation):

* before (issue 24; the last good state a ``copy.deepcopy`` of Adam's state every step, finiteness by
  ``isfinite(d).all()``): ratio 1.28 (200 steps × 5, mean step: trainer 48.7 ms, plain 38.0 ms), 1.33 and 1.25
  (150 × 4, median step); per step the deep copy cost 4.1 ms, the finiteness tests 5.2 ms, the
  parameter copy 1.3 ms (cProfile);
* after (copies into buffers allocated once, finiteness by one sum per tensor): ratio 1.13 and 1.19
  (150 × 4, median step; trainer 61.6 / 46.3 ms, plain 54.7 / 39.0 ms). Of the ~7 ms left, the
  snapshot is 4.6 ms (one copy of θ and of Adam's two moments, 3 × 7.4 MB, which an exact roll-back of
  an in-place update needs) and the finiteness tests 0.8 ms;
* the last good state copied every 10th step, not every step (the guard's ``snapshot_every``: a
  rejection rolls back to that copy, up to 9 good steps, which are redone): ratio 1.002 (150 × 3,
  median step; trainer 43.2 ms, plain 43.2 ms), within the issue's target (≤ 5 %).
"""

from __future__ import annotations

import argparse
import copy
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")


def setup(name: str):
    import pdeinv
    from pdeinv.io.runs import network
    from pdeinv.methods.presets import make_rule

    problem = pdeinv.load_problem(name)
    rule, hp = make_rule("adam", problem)
    spec = {"kind": "default", "rows_per_component": hp["rows_per_component"]}
    import torch

    torch.manual_seed(0)
    return problem, rule, hp, network(problem, spec)


def trainer_step_s(problem, rule, hp, model, steps: int) -> float:
    import pdeinv

    marks = {}

    def clock(record, _model):
        marks[record["step"]] = time.perf_counter()

    pdeinv.Trainer(problem, rule, model, steps=steps, batch_size=hp["batch_size"], eval_every=10 * steps,
                   callbacks=[clock], progress=False, prior=None).fit()
    return per_step(marks, steps)


def plain_step_s(problem, model, batch_size: int, steps: int, lr: float) -> float:
    import numpy as np
    import torch

    from pdeinv import apply
    from pdeinv.methods.base import y_loss
    from pdeinv.nets import fit_preconditioning
    from pdeinv.training.trainset import BATCH_ORDER, TRAIN_DATA, seed_stream

    _, y_np = problem.sample(1024, seed_stream(0, TRAIN_DATA))
    fit_preconditioning(model, y_np, problem.noise or None)
    dtype = next(model.parameters()).dtype
    y = torch.as_tensor(y_np, dtype=dtype)
    goal = None if dtype == torch.float64 else torch.as_tensor(np.asarray(y_np), dtype=torch.float64)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=lr)
    gen = torch.Generator().manual_seed(seed_stream(0, BATCH_ORDER))
    order, pos, marks = torch.randperm(len(y), generator=gen), 0, {}
    for step in range(1, steps + 1):
        if pos + batch_size > len(y):
            order, pos = torch.randperm(len(y), generator=gen), 0
        rows = order[pos:pos + batch_size]
        pos += batch_size
        opt.zero_grad(set_to_none=True)
        loss = y_loss(apply(problem.operator, model(y[rows])), y[rows] if goal is None else goal[rows])
        loss.backward()
        opt.step()
        marks[step] = time.perf_counter()
    return per_step(marks, steps)


def per_step(marks: dict, steps: int) -> float:
    """The median time between consecutive steps 10 … steps−1 (robust to a shared machine's pauses)."""
    return statistics.median(marks[k + 1] - marks[k] for k in range(10, steps - 1))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problem", default="heat_2d")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)

    from pdeinv.util.threads import limit

    limit(1)
    problem, rule, hp, model0 = setup(args.problem)
    trainer, plain = [], []
    for r in range(args.repeats):
        for side in ((0, 1) if r % 2 == 0 else (1, 0)):  # alternate which side goes first
            model = copy.deepcopy(model0)
            if side == 0:
                trainer.append(trainer_step_s(problem, rule, hp, model, args.steps))
            else:
                plain.append(plain_step_s(problem, model, hp["batch_size"], args.steps, hp["lr"]))
        print(f"repeat {r + 1}: trainer {1e3 * trainer[-1]:.2f} ms, plain {1e3 * plain[-1]:.2f} ms",
              flush=True)
    t, p = statistics.median(trainer), statistics.median(plain)
    print(f"{args.problem}, Adam, batch {hp['batch_size']}, {args.steps} steps x {args.repeats} (median): "
          f"trainer {1e3 * t:.2f} ms, plain {1e3 * p:.2f} ms per step; ratio {t / p:.3f}")


if __name__ == "__main__":
    main()
