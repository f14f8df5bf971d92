"""Every built-in scene × method × noise level, trained with the CLI's defaults, against best-α Tikhonov.

    OMP_NUM_THREADS=1 python benchmarks/accuracy.py [--scenes heat_1d,wave_2d] [--methods sip,adam]
        [--noise 0,0.01] [--out runs/accuracy]

Each cell runs ``pdeinv train SCENE --method M [--set noise=δ] --out DIR`` exactly as a user would
(no other flags: the preset's steps, batch, optimizer, target and stopping rule), reads its
``metrics.json``, and computes Tikhonov with the oracle α (``pdeinv.training.references.tikhonov_best`` on a
fine grid, α ≥ 1e-16·s_max²) on the same held-out pairs the run was tested on
(``problem.sample(N_TEST, seed_stream(0, TEST_DATA))``, the default test rows). Prints a markdown table
and writes ``OUT/accuracy.json``. One thread per run: timings are comparable within one invocation only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

SCENES = ["heat_1d", "heat_2d", "heat_plate", "advection_diffusion_2d", "reaction_diffusion_2d",
          "heat_sensors_2d", "wave_1d", "wave_2d", "wave_sensors_2d", "heat_3d", "heat_cavity_3d",
          "heat_sensors_3d", "wave_3d"]
GRID = tuple(10.0 ** (-k / 4) for k in range(0, 65))


def tikhonov(scene: str, noise: float) -> float:
    import pdeinv
    from pdeinv.training import references
    from pdeinv.training.trainset import N_TEST, TEST_DATA, seed_stream

    p = pdeinv.load_problem(scene, noise=noise)
    x, y = p.sample(N_TEST, seed_stream(0, TEST_DATA))
    return references.tikhonov_best(p, y, x, grid=GRID)["x_err"]


def train(scene: str, method: str, noise: float, out: Path, extra: tuple = ()) -> dict:
    """``metrics.json`` of ``pdeinv train SCENE --method M [--set noise=δ] *extra`` (``{"error": …}`` if it
    failed): no other flag but the output's."""
    cmd = [sys.executable, "-m", "pdeinv", "train", scene, "--method", method, "--out", str(out),
           "--overwrite", "--export-samples", "0", "--checkpoint-every", "0", *extra]
    if noise:
        cmd += ["--set", f"noise={noise:g}"]
    done = subprocess.run(cmd, capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1", "CI": "1"})
    if done.returncode:
        return {"error": (done.stderr.strip().splitlines() or ["?"])[-1][:160]}
    return json.loads((out / "metrics.json").read_text())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--methods", default="sip,adam")
    ap.add_argument("--noise", default="0,0.01")
    ap.add_argument("--out", default="runs/accuracy")
    args = ap.parse_args(argv)
    out = Path(args.out)
    rows = []
    for scene in args.scenes.split(","):
        for noise in (float(v) for v in args.noise.split(",")):
            row = {"scene": scene, "noise": noise, "tikhonov": tikhonov(scene, noise)}
            for method in args.methods.split(","):
                m = train(scene, method, noise, out / f"{scene}-{method}-{noise:g}")
                row[method] = {k: m.get(k) for k in ("x_err", "steps", "wall_s", "step_s", "stopped_by",
                                                     "error")}
            rows.append(row)
            cells = " | ".join(f"{row[m]['x_err']:.3g} ({row[m]['steps']} st, {row[m]['wall_s']:.0f} s)"
                               if row[m].get("x_err") is not None else f"({row[m].get('error')})"
                               for m in args.methods.split(","))
            print(f"| {scene} | {noise:g} | {cells} | {row['tikhonov']:.3g} |", flush=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / "accuracy.json").write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
