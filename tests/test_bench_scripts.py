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
])
def test_developer_benchmark_runs_on_its_smallest_setting(script, args, expect):
    run = subprocess.run([sys.executable, str(ROOT / script), *args], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    assert expect in run.stdout


@pytest.mark.parametrize("script", ["crossover.py", "scaling.py", "netsize.py", "ddp.py", "hig_step.py",
                                    "overhead.py", "nonlinear_references.py", "forward_bare.py"])
def test_developer_benchmark_says_how_to_run_it(script):
    doc = (ROOT / script).read_text().split('"""')[1]
    assert f"python benchmarks/{script}" in doc and "pdeinv.bench" not in (ROOT / script).read_text()
