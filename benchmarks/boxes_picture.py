"""True field, best-α Tikhonov, linear MMSE and a trained run's prediction for two held-out samples.

    python benchmarks/boxes_picture.py RUN_DIR --png docs/bench/heat_boxes.png [--samples 0,1]

``RUN_DIR``: a finished ``pdeinv train`` run (heat_boxes at the CLI defaults for the docs' picture);
the test samples are the run's own (``seed_stream(seed, TEST_DATA)``), the oracles as in
``benchmarks/linear_oracles.py`` (α and the ridge chosen on these samples).
"""

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from linear_oracles import best_mmse, best_tikhonov  # noqa: E402

from pdeinv.io.runs import load_run  # noqa: E402
from pdeinv.training.trainset import TEST_DATA, seed_stream  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("--png", required=True)
    ap.add_argument("--samples", default="0,1")
    ap.add_argument("--draws", type=int, default=16384)
    a = ap.parse_args()
    problem, model = load_run(a.run)
    xt, yt = problem.sample(128, seed_stream(0, TEST_DATA))
    err = lambda e: float(np.mean(problem.relative_error(e, xt)))  # noqa: E731
    tik = best_tikhonov(problem, xt, yt)
    mmse = best_mmse(problem, xt, yt, *problem.sample(a.draws, seed=12_345))
    with torch.no_grad():
        net = model(torch.as_tensor(yt, dtype=next(model.parameters()).dtype)).double().numpy()
    rows = [int(i) for i in a.samples.split(",")]
    cols = [("true x", xt), (f"Tikhonov, best α ({err(tik):.3f})", tik),
            (f"linear MMSE ({err(mmse):.3f})", mmse), (f"trained default ({err(net):.3f})", net)]
    mesh = problem.disc.basis.mesh
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(3.2 * len(cols), 3.0 * len(rows)), squeeze=False)
    for r, i in enumerate(rows):
        lim = np.abs(xt[i]).max()
        for c, (name, X) in enumerate(cols):
            ax = axes[r, c]
            v = problem.disc.vertex_values(X[i:i + 1])[0]
            ax.tripcolor(mesh.p[0], mesh.p[1], mesh.t.T, v, vmin=-lim * 0.2, vmax=lim, cmap="viridis")
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            rel = float(problem.relative_error(X[i:i + 1], xt[i:i + 1])[0])
            ax.set_title(f"{name}" if c == 0 else f"{name}\nthis sample {rel:.3f}", fontsize=8)
    fig.tight_layout()
    fig.savefig(a.png, dpi=90)
    print(f"-> {a.png}")


if __name__ == "__main__":
    main()
