"""The scaling benchmark (benchmarks/scaling.py): its --quick path runs and writes the whole table."""

import importlib.util
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "scaling.py"
_spec = importlib.util.spec_from_file_location("benchmarks_scaling", SCRIPT)
_scaling = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_scaling)
CASES, COLUMNS, QUICK = _scaling.CASES, _scaling.COLUMNS, _scaling.QUICK


def test_quick_scaling_table_has_every_case_and_column(tmp_path):
    out = tmp_path / "scaling.md"
    run = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--repeats", "1",
                          "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    lines = out.read_text().splitlines()
    assert lines[0].startswith("Made by `python benchmarks/scaling.py --quick")
    head = lines.index("| " + " | ".join(COLUMNS) + " |")
    rows = [[c.strip() for c in line.strip("|").split("|")]
            for line in lines[head + 2:] if line.startswith("|")]
    assert all(len(r) == len(COLUMNS) for r in rows)
    col = {c: i for i, c in enumerate(COLUMNS)}
    seen = {(int(r[col["dim"]]), int(r[col["n"]]), r[col["physics"]], r[col["backend"]]) for r in rows}
    expected = {(d, n, phys, b) for d, ns in QUICK.items() for n in ns for phys, b in CASES}
    assert seen == expected
    for r in rows:  # every case ran (tiny meshes: nothing is refused) and measured something
        assert float(r[col["build s"]]) > 0 and float(r[col["step s"]]) > 0, r
        assert float(r[col["peak MB"]]) >= 0, r
        N, n, dim = int(r[col["N"]]), int(r[col["n"]]), int(r[col["dim"]])
        assert N == (n - 1) ** dim  # interior unknowns of the unit square / cube
    amg = [r for r in rows if r[col["backend"]] == "steps+amg"]
    assert amg and all("AMGCG(" in r[col["note"]] and "rtol=" in r[col["note"]] for r in amg)
