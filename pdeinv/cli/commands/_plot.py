"""``training.png`` of ``pdeinv train``: the y-loss and the test errors against training wall time."""

from __future__ import annotations


def training_curves(history: list, path, title: str) -> None:
    """The batch y-loss (every step) and the test x- and y-errors (every evaluation) against training
    wall time, saved to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = [h["wall_s"] for h in history]
    ev = [h for h in history if "x_err" in h]
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.5), layout="constrained")
    loss = [h["loss"] for h in history]
    a.plot(t, loss, lw=0.8)
    a.set(xlabel="training wall time [s]", ylabel="batch y-loss ½‖P f(y*) − y*‖²", title=title)
    errors = [h[k] for h in ev for k in ("x_err", "y_err")]
    b.plot([h["wall_s"] for h in ev], [h["x_err"] for h in ev], "o-", label="x error")
    b.plot([h["wall_s"] for h in ev], [h["y_err"] for h in ev], "s-", label="y error")
    b.set(xlabel="training wall time [s]", ylabel="relative L²(Ω) error (test set)")
    for ax, values in ((a, loss), (b, errors)):  # log axes, unless nothing is positive (a zero loss)
        if any(isinstance(v, float | int) and 0 < v < float("inf") for v in values):
            ax.set_yscale("log")
    b.legend()
    fig.savefig(path, dpi=110)
    plt.close(fig)
