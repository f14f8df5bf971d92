"""Draw the accuracy table: x-error of each method per scene against best-α Tikhonov, noise-free and at 1 %.

    python benchmarks/accuracy_plot.py OUT/accuracy.json [MORE.json ...] --png docs/bench/accuracy.png
        [--merged ALL.json] [--table]

Reads the rows ``benchmarks/accuracy.py`` writes (later files override earlier ones cell by cell, so
partial re-runs merge), and draws one panel per noise level: a dot per method and scene, Tikhonov with
the oracle α as a bar. Log scale: noise-free wave scenes reach rounding. ``--table`` also prints the
markdown table of ``benchmarks/notes/results-history.md``: x-errors (the best trained method in bold),
ratios, and each method's mean step time (``metrics["step_s"]``: compare within a row, runs of one
invocation only).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from accuracy import SCENES  # noqa: E402  (the table's scene order)

METHODS = ("sip", "hig", "adam", "gd")


def merged(paths) -> dict:
    """``{(scene, noise): row}`` with later files' cells overriding earlier ones."""
    rows: dict = {}
    for path in paths:
        for row in json.loads(Path(path).read_text()):
            key = (row["scene"], row["noise"])
            rows.setdefault(key, {}).update({k: v for k, v in row.items() if v is not None})
    return rows


#: x-errors below this are rounding (noise-free wave scenes): their ratio is not reported
ROUNDING = 1e-8


def _fmt(v) -> str:
    return "–" if v is None else f"{v:.3g}"


def table(rows: dict, scenes: list) -> str:
    """The markdown table of :func:`merged` rows (module docstring)."""
    head = ("| scene | noise | " + " | ".join(m.upper() if m != "adam" else "Adam" for m in METHODS) +
            " | best-α Tikhonov | SIP / Tik. | HIG / Tik. | SIP / Adam | step ms SIP / HIG / Adam |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for scene in scenes:
        for noise in sorted(n for s, n in rows if s == scene):
            r = rows[(scene, noise)]
            err = {m: (r.get(m) or {}).get("x_err") for m in METHODS}
            best = min((v for v in err.values() if v is not None), default=None)
            cells = [f"**{_fmt(v)}**" if v is not None and v == best else _fmt(v) for v in err.values()]
            tik = r.get("tikhonov")

            def ratio(a, b):  # two errors at rounding (noise-free wave) have no meaningful ratio
                if a is None or not b:
                    return "–"
                return "both rounding" if max(a, b) < ROUNDING else _fmt(a / b)

            ms = " / ".join(_fmt(1e3 * (r.get(m) or {}).get("step_s")) if (r.get(m) or {}).get("step_s")
                            else "–" for m in ("sip", "hig", "adam"))
            ratios = [ratio(err["sip"], tik), ratio(err["hig"], tik), ratio(err["sip"], err["adam"])]
            lines.append(f"| {scene} | {noise:g} | " + " | ".join([*cells, _fmt(tik), *ratios, ms]) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", nargs="+")
    ap.add_argument("--png", required=True)
    ap.add_argument("--merged", default=None, help="also write the merged rows to this JSON file")
    ap.add_argument("--table", action="store_true", help="also print the markdown table")
    args = ap.parse_args(argv)
    rows = merged(args.json)
    if args.merged:
        Path(args.merged).write_text(json.dumps([{"scene": s, "noise": n, **r} for (s, n), r in rows.items()],
                                                indent=1))
    scenes = sorted(dict.fromkeys(s for s, _ in rows), key=lambda s: SCENES.index(s) if s in SCENES else 99)
    noises = sorted({n for _, n in rows})
    if args.table:
        print(table(rows, scenes))
    fig, axes = plt.subplots(1, len(noises), figsize=(6 * len(noises), 4.2), squeeze=False)
    for ax, noise in zip(axes[0], noises, strict=True):
        xs = range(len(scenes))
        tik = [rows.get((s, noise), {}).get("tikhonov") for s in scenes]
        ax.bar(xs, [t or 0 for t in tik], color="0.85", label="best-α Tikhonov (oracle α)")
        for i, method in enumerate(METHODS):
            cells = [(j, rows.get((s, noise), {}).get(method) or {}) for j, s in enumerate(scenes)]
            vals = [(j, c["x_err"]) for j, c in cells if c.get("x_err") is not None]
            if vals:
                ax.plot([j + 0.15 * (i - 1.5) for j, _ in vals], [v for _, v in vals], "o", ms=5,
                        label=method + (" (default)" if method == "sip" else ""))
        ax.set_yscale("log")
        ax.set_xticks(list(xs), scenes, rotation=60, ha="right", fontsize=8)
        ax.set_ylabel("relative L²(Ω) x-error on the test pairs")
        ax.set_title("noise-free" if noise == 0 else f"{noise:.0%} noise")
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.suptitle("pdeinv train SCENE --method M (CLI defaults) against the classical solve")
    fig.tight_layout()
    fig.savefig(args.png, dpi=110)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
