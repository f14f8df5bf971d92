"""Data-parallel speed-up measured in one run.

    python benchmarks/ddp.py [--procs 2] [--steps 6] [--batch-size 16] [--repeats 1]

(smallest setting: ``--steps 2 --batch-size 4 --scene 'wave_1d --set n=16'``)

Trains the same physics-bound scene twice, one after the other, each process with one
thread (``OMP_NUM_THREADS=1``, ``--threads 1``):

* one process: ``python -m pdeinv train SCENE …``;
* ``P`` processes: ``torchrun --standalone --nproc_per_node=P -m pdeinv train SCENE …``,

with the same seed and global batch, and prints ``step_s`` of each (training wall time per
step from ``metrics.json``: no imports, data generation or evaluation), their ratio (the
speed-up) and the relative difference of the final losses. Default scene: wave_2d on a
64×64 mesh with time stepping (3969 unknowns, 50 Newmark steps: each step of Adam runs the
batch forward and back through 50 sparse solves, so the physics dominates). On a machine
shared with other jobs the ratio is a snapshot; ``--repeats`` takes the best of several.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

SCENE = ["wave_2d", "--set", "n=64", "--set", "backend=steps"]


def _train(launcher: list, argv: list, out: Path) -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run([*launcher, "-m", "pdeinv", "train", *argv, "--out", str(out), "--overwrite"],
                          env=env, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"benchmarks/ddp.py: {' '.join(launcher)} failed ({done.returncode}): "
                         f"{done.stderr.strip()[-500:]}")
    return json.loads((out / "metrics.json").read_text())


def measure(procs: int = 2, steps: int = 6, batch: int = 16, repeats: int = 1, scene: list = SCENE) -> dict:
    """``step_s`` with 1 and ``procs`` processes (best of ``repeats``), the speed-up, the loss agreement."""
    argv = [*scene, "--method", "adam", "--steps", str(steps), "--batch-size", str(batch),
            "--n-train", str(2 * batch), "--n-test", "8", "--eval-every", str(steps), "--export-samples",
            "0", "--checkpoint-every", "0", "--threads", "1", "--seed", "0"]
    one_cmd = [sys.executable]
    many_cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={procs}"]
    best = {1: None, procs: None}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):  # interleaved, so a burst of load hits both alike
            for p, cmd in ((1, one_cmd), (procs, many_cmd)):
                m = _train(cmd, argv, Path(tmp) / f"{p}-{r}")
                if best[p] is None or m["step_s"] < best[p]["step_s"]:
                    best[p] = m
    one, many = best[1], best[procs]
    return {"scene": " ".join(scene), "steps": steps, "batch": batch, "processes": procs,
            "step_s_1": one["step_s"], f"step_s_{procs}": many["step_s"],
            "speedup": one["step_s"] / many["step_s"], "world_size": many["world_size"],
            "loss_rel_diff": abs(many["loss"] - one["loss"]) / abs(one["loss"]),
            "cpus": os.cpu_count(), "load_1min": os.getloadavg()[0]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python benchmarks/ddp.py", description=__doc__.splitlines()[0])
    p.add_argument("--procs", type=int, default=2)
    p.add_argument("--steps", type=int, default=6)
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--scene", default=" ".join(SCENE), metavar="'SCENE [--set K=V ...]'",
                   help=f"the scene and its --set flags, one string (default: {' '.join(SCENE)!r})")
    a = p.parse_args(argv)
    r = measure(a.procs, a.steps, a.batch_size, a.repeats, a.scene.split())
    print(json.dumps(r, indent=2))
    many = r[f"step_s_{r['processes']}"]
    print(f"{r['processes']} processes vs 1 on {r['scene']} (batch {r['batch']}): {r['step_s_1']:.3f} -> "
          f"{many:.3f} s/step, speed-up x{r['speedup']:.2f} ({r['cpus']} cpus, load {r['load_1min']:.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
