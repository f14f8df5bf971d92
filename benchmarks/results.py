"""Regenerate docs/results.md: ``pdeinv train`` with its default flags on a list of scenes.

    python benchmarks/results.py [--quick] [--scenes heat_2d "heat_boxes --set n=32"] [--noise 0 0.01]
        [--methods sip] [--out docs/results.md]

Each row runs ``pdeinv train SCENE [FLAGS] [--set noise=δ] --seed 0 --threads 1 --out DIR`` in a temporary
folder, one run at a time, exactly as a user would (the preset's steps, the default prior stage), reads
its ``metrics.json`` and writes one markdown page: the date (UTC), the git commit (``+dirty`` when the
working tree has changes), a table (scene, noise, method, the rule stage's x-error, the final x- and
y-errors, what the prior stage did, seconds) and the exact command of each row.

The default scenes are heat_2d, heat_boxes at n = 32, heat_1d and wave_2d, each noise-free and at 1 %
noise. ``--quick``: the same scenes at n = 16 with ``--prior-fit 200`` (a few minutes on 2 cores).
``--scenes`` takes a scene name with its own flags, quoted as one word: ``"heat_boxes --set n=64"``.
``make results`` runs the default list.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the default rows: a scene with its own flags (each also at every ``--noise`` level)
SCENES = ["heat_2d", "heat_boxes --set n=32", "heat_1d", "wave_2d"]
#: ``--quick``: CI-sized meshes and a capped prior stage
QUICK = ["heat_2d --set n=16", "heat_boxes --set n=16", "heat_1d --set n=16", "wave_2d --set n=16"]
QUICK_FLAGS = ["--prior-fit", "200"]
#: the flags every row adds: one seed, one thread (timings comparable within one page)
FIXED = ["--seed", "0", "--threads", "1"]


def command(scene: str, noise: float, method: str = "sip", extra: tuple = ()) -> list[str]:
    """``pdeinv train …`` of one row, without ``--out``: ``scene`` is a name with its own flags."""
    name, *flags = shlex.split(scene)
    cmd = ["pdeinv", "train", name, *flags, *extra]
    if method != "sip":
        cmd += ["--method", method]
    if noise:
        cmd += ["--set", f"noise={noise:g}"]
    return cmd + FIXED


def run(cmd: list[str], out: Path) -> dict:
    """Run ``cmd`` (``pdeinv train …``) with ``--out out``: ``{"metrics", "seconds", "returncode",
    "error"}``; ``metrics`` is ``None`` when the run wrote none (exit code 3, a failed verdict, still
    writes it)."""
    exe = [sys.executable, "-m", "pdeinv", *cmd[1:], "--out", str(out)]
    t0 = time.perf_counter()
    done = subprocess.run(exe, capture_output=True, text=True, cwd=out.parent,
                          env={**os.environ, "OMP_NUM_THREADS": "1", "CI": "1"})
    seconds = time.perf_counter() - t0
    metrics_file = out / "metrics.json"
    metrics = json.loads(metrics_file.read_text()) if metrics_file.is_file() else None
    error = None
    if done.returncode:
        error = (done.stderr.strip().splitlines() or [f"exit code {done.returncode}"])[-1][:200]
    return {"metrics": metrics, "seconds": seconds, "returncode": done.returncode, "error": error}


def git_commit(root: Path = ROOT) -> str:
    """``git rev-parse --short HEAD``, with ``+dirty`` when ``git status --porcelain`` lists changes."""
    def git(*args):
        return subprocess.run(["git", *args], capture_output=True, text=True, cwd=root).stdout.strip()

    head = git("rev-parse", "--short", "HEAD") or "unknown"
    return head + ("+dirty" if git("status", "--porcelain") else "")


def _version(package: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:
        return "?"


def _g(value, digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}g}"


def _prior_cell(stage: dict | None) -> str:
    """What the prior stage did, in one table cell."""
    if stage is None:
        return "none (the network has no prior part, or `--prior-fit 0`)"
    if stage.get("skipped"):
        return f"skipped: {stage['skipped']}"
    steps = f"{stage.get('steps', 0)} steps" + (f" of at most {stage['max_steps']}"
                                                if stage.get("max_steps") else "")
    kept = "kept" if stage.get("kept") else "not kept (it did not lower the held-out error)"
    return f"{kept}: {stage.get('draws', '?')} draws, {steps}"


def table_row(row: dict, i: int) -> str:
    """One markdown table row of ``row`` (:func:`run`'s result plus ``scene``, ``noise``, ``method``)."""
    m = row.get("metrics")
    if m is None:
        return (f"| {i} | {row['scene']} | {row['noise']:g} | {row['method']} | – | – | – | "
                f"failed: {row.get('error') or '?'} | – |")
    stages = {st["name"]: st for st in m.get("stages", [])}
    rule = stages.get(m.get("method", row["method"])) or (m.get("stages") or [{}])[0]
    final_x = _g(m.get("x_err"))
    if m.get("failed"):
        final_x += f" (failed: {m['failed']})"
    return (f"| {i} | {row['scene']} | {row['noise']:g} | {m.get('method', row['method'])} | "
            f"{_g(rule.get('x_err'))} | {final_x} | {_g(m.get('y_err'))} | "
            f"{_prior_cell(stages.get('prior'))} | "
            f"{m.get('wall_s', 0):.1f} ({row['seconds']:.0f}) |")


def page(rows: list[dict], *, date: str | None = None, commit: str | None = None, quick: bool = False,
         argv: list[str] | None = None) -> str:
    """docs/results.md for ``rows`` (each: ``scene``, ``noise``, ``method``, ``command`` (a list),
    ``metrics`` (metrics.json, or ``None``), ``seconds``, ``error``)."""
    date = date or datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    commit = commit or git_commit()
    shown = list(argv or [])
    if "--out" in shown:  # where the page went is no part of how it was made
        i = shown.index("--out")
        del shown[i:i + 2]
    made = shlex.join(["python", "benchmarks/results.py", *shown])

    lines = [
        "# Results",
        "",
        "[← README](../README.md) · what `pdeinv train` with its default flags reaches on a few built-in "
        "scenes, noise-free and at 1 % noise. Every number below comes from the run's `metrics.json` "
        "([what each one means](train.md#metricsjson)); this page is written by "
        "`benchmarks/results.py`, never by hand.",
        "",
        f"- **Made** {date}, commit `{commit}`, by `{made}`" + (" (`--quick`: the scenes at n = 16, "
                                                                "`--prior-fit 200`)" if quick else ""),
        f"- **Machine** {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"torch {_version('torch')}, one thread per run (`--threads 1`), one run at a time",
        "- **Regenerate** `make results` (the default scenes) or `python benchmarks/results.py --quick` "
        "(n = 16, a few minutes)",
        "",
        "| # | scene | noise | method | rule stage x_err | final x_err | final y_err | prior stage | "
        "train s (command s) |",
        "|---|---|---|---|---|---|---|---|---|",
        *(table_row(row, i) for i, row in enumerate(rows, 1)),
        "",
        "Columns: **rule stage x_err**, the held-out relative L²(Ω) error after the update rule's stage "
        "(`stages[0].x_err`); **final x_err** and **final y_err**, the held-out errors of the model the run "
        "saved (`x_err`, `y_err`); **prior stage**, whether the prior stage ran and was kept, on how many "
        "prior draws and for how many steps, or why it was skipped; **train s**, the seconds of the two "
        "stages (`wall_s`), and in brackets the whole command's (building the problem and drawing the "
        "data included). Every budget is a count (steps, draws), never seconds: the same command and seed "
        "train the same model on an idle or a loaded machine, and only the seconds change.",
        "",
        "## Commands",
        "",
        "```bash",
        *(f"{shlex.join(row['command'])} --out runs/{i}  # row {i}" for i, row in enumerate(rows, 1)),
        "```",
        "",
        "Older measurements (every scene and method against best-α Tikhonov, the bench, scaling against the "
        "mesh, nonlinear physics) are kept as lab notes in "
        "[benchmarks/notes/](../benchmarks/notes/README.md).",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the scenes at n = 16, --prior-fit 200")
    ap.add_argument("--scenes", nargs="+", default=None,
                    help=f"scenes, each with its own flags as one quoted word (default: {'; '.join(SCENES)})")
    ap.add_argument("--noise", nargs="+", type=float, default=[0.0, 0.01],
                    help="noise levels (default 0 0.01)")
    ap.add_argument("--methods", nargs="+", default=["sip"], help="update rules (default sip)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results.md"),
                    help="the page (default docs/results.md)")
    args = ap.parse_args(argv)
    scenes = args.scenes or (QUICK if args.quick else SCENES)
    extra = tuple(QUICK_FLAGS) if args.quick else ()
    rows = []
    with tempfile.TemporaryDirectory(prefix="pdeinv-results-") as tmp:
        for scene in scenes:
            for noise in args.noise:
                for method in args.methods:
                    cmd = command(scene, noise, method, extra)
                    print(shlex.join(cmd), flush=True)
                    done = run(cmd, Path(tmp) / f"run{len(rows) + 1}")
                    row = {"scene": scene, "noise": noise, "method": method, "command": cmd, **done}
                    rows.append(row)
                    print(table_row(row, len(rows)), flush=True)
    text = page(rows, quick=args.quick, argv=list(sys.argv[1:] if argv is None else argv))
    Path(args.out).write_text(text)
    print(f"wrote {args.out}")
    return 0 if all(r["metrics"] is not None for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
