"""A scene trained on a data file from another prior, at the CLI defaults, against the linear oracles.

    python benchmarks/outside_data.py boxes 0.01 [--scene heat_2d] [--rows 1152] [--out /tmp/outside]

Draws ``rows`` pairs of ``SCENE`` with ``--set prior=PRIOR`` (``pdeinv.problem.sampling.PRIORS``) and noise
``NOISE`` into a ``.npz`` file, trains ``pdeinv train SCENE --data FILE`` without other flags (the
file's last 128 rows are its test set), and prints the run's x-error beside best-α Tikhonov and the
linear MMSE fitted on the file's *training* x (both with the best regularization, chosen on the test
rows: oracles).
"""

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from linear_oracles import best_mmse, best_tikhonov

import pdeinv


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("prior")
    ap.add_argument("noise", type=float)
    ap.add_argument("--scene", default="heat_2d")
    ap.add_argument("--rows", type=int, default=1152)
    ap.add_argument("--out", default="/tmp/outside")
    a = ap.parse_args()
    n_test = 128
    p = pdeinv.load_problem(a.scene, prior=a.prior, noise=a.noise)
    x, y = p.sample(a.rows, seed=77)
    out = Path(a.out) / f"{a.scene}_{a.prior}_{a.noise}"
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(f"{out}.npz", x=x, y=y)
    cmd = [sys.executable, "-m", "pdeinv", "train", a.scene, "--data", f"{out}.npz",
           "--set", f"noise={a.noise}", "--seed", "0", "--out", str(out), "--overwrite", "--threads", "1"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    rc = subprocess.run(cmd, capture_output=True, text=True, env=env).returncode
    m = json.loads((out / "metrics.json").read_text())
    xt, yt, xtr, ytr = x[-n_test:], y[-n_test:], x[:-n_test], y[:-n_test]
    err = lambda e: float(np.mean(p.relative_error(e, xt)))  # noqa: E731
    mmse, tik = err(best_mmse(p, xt, yt, xtr, ytr)), err(best_tikhonov(p, xt, yt))
    fit = m.get("prior_fit", {})
    print(f"{a.scene} file prior={a.prior} noise={a.noise}: exit {rc}, default {m['x_err']:.4f} (linear part "
          f"{fit.get('error_before')}, correction kept {fit.get('kept')}), MMSE of the file's x {mmse:.4f}, "
          f"best-α Tikhonov {tik:.4f}, {m['wall_s']:.0f} s")


if __name__ == "__main__":
    main()
