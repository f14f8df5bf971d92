"""The developer benchmarks in benchmarks/ (scripts on the public API, not run by ``pdeinv bench``)
run on their smallest settings and print their tables (scaling: tests/test_scaling.py; ddp needs
torchrun and two processes: run by hand, see its docstring)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.mark.parametrize("script, args, expect", [
    ("crossover.py", ["--dims", "2", "--scenes", "heat", "--sizes2", "8", "--repeats", "1"],
     "crossover 2-D heat"),
    ("netsize.py", ["--sizes", "4", "--steps", "2", "--nets", "whitened"], "| 4 | 9 | whitened | sip |"),
    ("hig_step.py", ["--scenes", "heat_1d", "--steps", "4", "--repeats", "1"], "heat_1d: 4 steps x 1"),
    ("nonlinear_references.py", ["sine_gordon_1d", "--set", "n=16", "--n-test", "4", "--alphas", "0.1"],
     "sine_gordon_1d n=16 oracle: x_err"),
    ("forward_bare.py", ["--n", "12", "--batch", "4", "--repeats", "1"], "relative difference"),
    ("sip_heat.py", ["--n", "8", "--steps", "2", "--every", "1", "--methods", "sip", "adam"],
     "| sip, linear map |"),
    ("sip_heat.py", ["--problem", "allen_cahn_1d", "--set", "n=16", "--steps", "2", "--every", "1",
                     "--methods", "sip"], "| Gauss–Newton oracle (rel. α"),
    ("posterior.py", ["heat_1d", "--set", "n=16", "--set", "prior=grf", "--steps", "2", "--prior-fit", "0",
                      "--check", "50", "--draws", "512"], '"std_ratio_median"'),
])
def test_developer_benchmark_runs_on_its_smallest_setting(script, args, expect):
    run = subprocess.run([sys.executable, str(ROOT / script), *args], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    assert expect in run.stdout


@pytest.mark.parametrize("script", ["crossover.py", "scaling.py", "netsize.py", "ddp.py", "hig_step.py",
                                    "overhead.py", "nonlinear_references.py", "forward_bare.py",
                                    "results.py", "sip_heat.py", "posterior.py"])
def test_developer_benchmark_says_how_to_run_it(script):
    doc = (ROOT / script).read_text().split('"""')[1]
    assert f"python benchmarks/{script}" in doc and "pdeinv.bench" not in (ROOT / script).read_text()


def _results_script():
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_results", ROOT / "results.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_results_page_from_metrics_without_training():
    """benchmarks/results.py's page (docs/results.md) from fake metrics.json dicts: the date, the commit,
    a row per run with the rule stage's and the final errors and what the prior stage did, and the
    exact commands; a run that wrote no metrics is a row that says so."""
    import re

    results = _results_script()
    kept = {"method": "sip", "x_err": 0.16, "y_err": 2e-9, "wall_s": 400.0, "failed": None,
            "stages": [{"name": "sip", "steps": 30, "seconds": 3.0, "stopped_by": "steps", "x_err": 0.369,
                        "y_err": 9e-13},
                       {"name": "prior", "kept": True, "draws": 65536, "held_out": 8192, "steps": 8192,
                        "max_steps": 8192, "seconds": 397.0, "x_err": 0.16, "y_err": 2e-9}]}
    skipped = {"method": "sip", "x_err": 0.00156, "y_err": 1.79e-12, "wall_s": 3.16, "failed": None,
               "stages": [{"name": "sip", "steps": 30, "x_err": 0.00156, "y_err": 1.79e-12},
                          {"name": "prior", "kept": False, "skipped": "the rule's estimate is within 0.0014",
                           "seconds": 0.01}]}
    rows = [{"scene": "heat_boxes --set n=32", "noise": 0.0, "method": "sip", "metrics": kept,
             "seconds": 410.0, "command": results.command("heat_boxes --set n=32", 0.0), "error": None},
            {"scene": "heat_2d", "noise": 0.01, "method": "sip", "metrics": skipped, "seconds": 20.0,
             "command": results.command("heat_2d", 0.01), "error": None},
            {"scene": "wave_2d", "noise": 0.0, "method": "sip", "metrics": None, "seconds": 1.0,
             "command": results.command("wave_2d", 0.0), "error": "pdeinv train: error: out of memory"}]
    text = results.page(rows, date="2030-01-02 03:04 UTC", commit="abc1234+dirty", quick=True,
                        argv=["--quick", "--out", "/tmp/x.md"])
    assert "2030-01-02 03:04 UTC" in text and "`abc1234+dirty`" in text
    assert "`python benchmarks/results.py --quick`" in text  # where the page went is not shown
    assert "| 1 | heat_boxes --set n=32 | 0 | sip | 0.369 | 0.16 | 2e-09 | kept: 65536 draws, 8192 steps" \
        in text
    assert "| 2 | heat_2d | 0.01 | sip | 0.00156 | 0.00156 | 1.79e-12 | skipped: the rule's estimate" in text
    assert "| 3 | wave_2d | 0 | sip | – | – | – | failed: pdeinv train: error: out of memory" in text
    assert ("pdeinv train heat_boxes --set n=32 --seed 0 --threads 1 --out runs/1" in text
            and "pdeinv train heat_2d --set noise=0.01 --seed 0 --threads 1 --out runs/2" in text)
    default = results.page(rows[:1])  # today's date in UTC, and the checkout's commit
    made = r"\*\*Made\*\* \d{4}-\d\d-\d\d \d\d:\d\d UTC, commit `([0-9a-f]{4,}(\+dirty)?|unknown)`"
    assert re.search(made, default)

