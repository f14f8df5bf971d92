"""The benchmark's PNG plots (matplotlib, Agg backend, small files)."""

from __future__ import annotations

import math


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def forward_pareto(points: list[dict], front: list[int], path, title: str, dpi: int = 80) -> None:
    """Relative L²(Ω) error against forward time, one marker per backend, the Pareto front joined."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 4), layout="constrained")
    ok = [p for p in points if p.get("outcome") == "ok" and p["error"] > 0]
    for backend in dict.fromkeys(p["backend"] for p in ok):
        pts = [p for p in ok if p["backend"] == backend]
        ax.loglog([p["time_s"] for p in pts], [p["error"] for p in pts], "o", label=backend, alpha=0.8)
    fr = sorted((points[i] for i in front), key=lambda p: p["time_s"])
    if fr:
        ax.loglog([p["time_s"] for p in fr], [p["error"] for p in fr], "k--", lw=0.8, label="Pareto front")
    ax.set(xlabel="forward time, batch of 16 [s]", ylabel="relative L²(Ω) error vs exact", title=title)
    if ax.get_legend_handles_labels()[0]:  # no point with an error above 0: no legend (matplotlib warns)
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def methods(results: dict, reference: dict | None, path, title: str, dpi: int = 80) -> None:
    """Test x- and y-error against training wall time per method, references (``None``: none, nonlinear
    physics) as horizontal lines."""
    plt = _plt()
    fig, (ax, ay) = plt.subplots(1, 2, figsize=(12, 4), layout="constrained")
    for name, r in results.items():
        c = [row for row in r.get("curve", []) if all(math.isfinite(v) for v in row)]
        if c:
            ax.semilogy([row[0] for row in c], [row[1] for row in c], "o-", ms=3, label=name)
            ay.semilogy([row[0] for row in c], [row[2] for row in c], "o-", ms=3, label=name)
    lines = (("mmse_x_err", "--", "linear MMSE"), ("tikhonov_best_x_err", ":", "best-α Tikhonov"),
             ("filter_best_x_err", "-.", "best spectral filter"))
    for key, ls, label in lines:
        v = (reference or {}).get(key)
        if v is not None and math.isfinite(v) and v > 0:
            ax.axhline(v, ls=ls, color="k", lw=1, label=label)
    ax.set(xlabel="training wall time [s]", ylabel="test x-error (relative L²(Ω))", title=title)
    ay.set(xlabel="training wall time [s]", ylabel="test y-error (relative L²(Ω))")
    if ax.get_legend_handles_labels()[0]:
        fig.legend(*ax.get_legend_handles_labels(), loc="outside right upper", fontsize=7)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
