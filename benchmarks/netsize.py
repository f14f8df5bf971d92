"""Network size against the mesh: the whitened linear map (``N²`` parameters) against ``nets.reduced``.

    OMP_NUM_THREADS=1 python benchmarks/netsize.py [--sizes 32 64 128] [--method sip] [--steps 1000]
        [--nets whitened reduced]

(smallest setting: ``--sizes 8 --steps 5``, seconds)

Trains each network on heat_2d at each ``n`` with the CLI's defaults (``make_rule``,
1024 training and 128 test samples, seed 0, one torch thread) and prints a markdown
row: trained parameters, buffers, test x-error (relative L²(Ω)), seconds per step
(training steps only, ``metrics['step_s']``) and the peak resident set of the process.
"""

from __future__ import annotations

import argparse
import resource

import torch

from pdeinv import nets

NETS = {"whitened": lambda: nets.whitened("linear"),
        "reduced": lambda: nets.reduced(),
        "reduced_linear": lambda: nets.reduced(body="linear"),
        "reduced_mlp": lambda: nets.reduced(body="mlp")}


def row(n: int, net: str, method: str, steps: int, seed: int = 0) -> dict:
    from pdeinv import Trainer, load_problem
    from pdeinv.methods.presets import make_rule

    problem = load_problem("heat_2d", n=n)
    rule, hp = make_rule(method, problem, problem.noise)
    torch.manual_seed(seed)
    model = NETS[net]()(problem)
    result = Trainer(problem, rule, model, steps=steps, n_train=1024, n_test=128,
                     batch_size=hp["batch_size"], seed=seed, progress=False, prior=None).fit()
    m = result.metrics
    return {"n": n, "N": problem.N, "net": net, "method": method,
            "params": sum(p.numel() for p in model.parameters()),
            "buffers": sum(b.numel() for b in model.buffers()),
            "x_err": m["x_err"], "step_s": m["step_s"], "steps": m["steps"],
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python benchmarks/netsize.py")
    ap.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    ap.add_argument("--nets", nargs="+", default=list(NETS), choices=list(NETS))
    ap.add_argument("--method", default="sip")
    ap.add_argument("--steps", type=int, default=1000)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    print("| n | N | network | method | trained params | buffers | x-error | s/step | peak RSS GB |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        for net in args.nets:
            r = row(n, net, args.method, args.steps)
            print(f"| {r['n']} | {r['N']} | {r['net']} | {r['method']} | {r['params']:,} | "
                  f"{r['buffers']:,} | "
                  f"{r['x_err']:.4f} | {r['step_s']:.4f} | {r['peak_rss_gb']:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
