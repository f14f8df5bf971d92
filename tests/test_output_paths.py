"""One output-path policy for every command (pdeinv.util.outpaths): missing folders created, a read-only
folder refused in one line (exit 2, no traceback), never an input or a run's own files overwritten
(``show --png RUN/training.png`` once replaced the run's training curves)."""

from __future__ import annotations

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.util.outpaths import OutputPathError, output_file, output_folder

pytestmark = pytest.mark.usefixtures("one_thread")

SMALL = ["--set", "n=16", "--set", "steps=10", "--hidden", "8", "--n-train", "16", "--n-test", "8",
         "--batch-size", "8", "--steps", "2", "--threads", "1", "--export-samples", "2"]
#: a folder no one can write into, root included (tests run as root in CI's container)
READ_ONLY = "/proc"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A finished run (with fields.vtu) and an observation file of its problem."""
    d = tmp_path_factory.mktemp("paths")
    assert main(["train", "--prior-fit", "0", "heat_1d", *SMALL, "--out", str(d / "run")]) == 0
    x, y = pdeinv.load_problem("heat_1d", n=16, steps=10).sample(4, seed=5)
    np.savez(d / "obs.npz", x=x, y=y)
    return d


def _snapshot(folder):
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _refused(capsys, argv, match, folder):
    before = _snapshot(folder)
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err and match in err, err
    assert _snapshot(folder) == before  # nothing overwritten, nothing left behind


@pytest.mark.parametrize("argv, match", [
    (["show", "{run}", "--png", "{run}/training.png"], "is one of a run's own files (training.png)"),
    (["show", "{run}", "--png", "{run}/metrics.json"], "is one of a run's own files (metrics.json)"),
    (["show", "{run}", "--png", "{run}/fields.vtu"], "is the same file as the fields file drawn"),
    (["predict", "{run}", "--data", "{d}/obs.npz", "--out", "{d}/p.npz", "--vtu", "{run}/fields.vtu"],
     "--vtu '{run}/fields.vtu' is one of a run's own files"),
    (["classical", "heat_1d", "--set", "n=16", "--data", "{d}/obs.npz", "--out", "{run}/metrics.json"],
     "is one of a run's own files (metrics.json)"),
    (["classical", "heat_1d", "--set", "n=16", "--data", "{d}/obs.npz", "--out", "{d}/obs.npz"],
     "is the same file as --data"),
    (["show", "{run}", "--png", f"{READ_ONLY}/f.png"], f"--png '{READ_ONLY}/f.png': '{READ_ONLY}' is not a "
                                                       "writable directory"),
    (["predict", "{run}", "--data", "{d}/obs.npz", "--out", f"{READ_ONLY}/p.npz"],
     "is not a writable directory"),
    (["predict", "{run}", "--data", "{d}/obs.npz", "--out", "{d}/p.npz", "--vtu", f"{READ_ONLY}/sub/p.vtu"],
     "is not a writable directory"),
    (["classical", "heat_1d", "--set", "n=16", "--data", "{d}/obs.npz", "--out", f"{READ_ONLY}/c.json"],
     "is not a writable directory"),
    (["show", "{run}", "--png", "{d}/obs.npz/f.png"], "is not a writable directory (a file is in the way)"),
    (["train", "--prior-fit", "0",
      "heat_1d", *SMALL, "--out", f"{READ_ONLY}/run"], "is not a writable directory"),
    # bench and stress wrote bench.json, forward.png, methods.png / stress.json into any folder, exit 0
    (["bench", "heat_1d", "--quick", "--set", "n=8", "--out", "{run}"], "holds .pdeinv-run, checkpoint.pt"),
    (["bench", "heat_1d", "--quick", "--set", "n=8", "--out", "{d}"], "holds obs.npz, run: it is not"),
    (["stress", "heat_1d", "--quick", "--set", "n=8", "--out", "{run}"], "more: it is not a folder"),
    (["stress", "heat_1d", "--quick", "--set", "n=8", "--out", "{d}"], "holds obs.npz, run: it is not"),
], ids=["show-training-png", "show-metrics", "show-its-input", "predict-vtu-run-file", "classical-metrics",
        "classical-its-data", "show-read-only", "predict-read-only", "predict-vtu-read-only",
        "classical-read-only", "show-under-a-file", "train-read-only", "bench-into-a-run",
        "bench-into-a-folder",
        "stress-into-a-run", "stress-into-a-folder"])
def test_refused_in_one_line(run, capsys, argv, match):
    fill = {"{run}": str(run / "run"), "{d}": str(run)}
    for k, v in fill.items():
        argv = [a.replace(k, v) for a in argv]
        match = match.replace(k, v)
    _refused(capsys, argv, match, run)


def test_missing_folders_are_created_for_every_command(run, tmp_path, capsys):
    d, r = str(run), str(run / "run")
    assert main(["show", r, "--png", str(tmp_path / "a" / "b" / "f.png")]) == 0
    assert main(["predict", r, "--data", f"{d}/obs.npz", "--out", str(tmp_path / "c" / "p.npz"),
                 "--vtu", str(tmp_path / "d" / "e" / "p.vtu")]) == 0
    assert main(["classical", "heat_1d", "--set", "n=16", "--set", "steps=10", "--data", f"{d}/obs.npz",
                 "--out", str(tmp_path / "f" / "c.json")]) == 0
    capsys.readouterr()
    for path in ("a/b/f.png", "c/p.npz", "d/e/p.vtu", "f/c.json"):
        assert (tmp_path / path).is_file(), path
    assert main(["show", r]) == 0  # the default DIR/fields.png is show's own file: redrawn


def test_a_prediction_kept_in_a_run_folder_is_replaced_with_overwrite(run, capsys):
    """An earlier ``predict --out RUN/p.npz`` is not one of the run's own files: refused without
    --overwrite as any existing file, replaced with it; the run's files stay as they were."""
    d, r = str(run), str(run / "run")
    own = {p: p.read_bytes() for p in (run / "run").iterdir() if p.is_file()}
    argv = ["predict", r, "--data", f"{d}/obs.npz", "--out", f"{r}/kept.npz", "-q"]
    assert main(argv) == 0
    assert main(argv) == 2
    assert "kept.npz' exists; pass --overwrite" in capsys.readouterr().err
    assert main([*argv, "--overwrite"]) == 0
    assert all(p.read_bytes() == b for p, b in own.items())
    (run / "run" / "kept.npz").unlink()


def test_save_run_creates_its_folder_and_loads_back(tmp_path):
    p = pdeinv.load_problem("heat_1d", n=8)
    result = pdeinv.train(p, "sip", n_train=8, n_test=4, steps=1, progress=False, prior=None)
    out = pdeinv.save_run(tmp_path / "a" / "b", "heat_1d", {"n": 8}, model=result.model)
    problem, model = pdeinv.load_run(out)
    y = p.sample(2, seed=1)[1]
    np.testing.assert_allclose(pdeinv.io.export.predict(model, y), pdeinv.io.export.predict(result.model, y))


def test_the_policy_functions(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "run.json").write_text('{"format": "pdeinv-run"}')  # pdeinv's own record
    (tmp_path / "run" / "model.pt").write_text("weights")
    (tmp_path / "run" / "notes.txt").write_text("a user's notes")
    with pytest.raises(OutputPathError, match=r"out '' is empty"):
        output_file("", "out")
    with pytest.raises(OutputPathError, match=r"is one of a run's own files \(model\.pt\)"):
        output_file(tmp_path / "run" / "model.pt")
    with pytest.raises(OutputPathError, match=r"notes\.txt' exists; pass overwrite=True"):
        output_file(tmp_path / "run" / "notes.txt")  # not the run's own: the rule of every other file
    assert output_file(tmp_path / "run" / "notes.txt", overwrite=True).name == "notes.txt"
    with pytest.raises(OutputPathError, match=r"is one of a run's own files \(model\.pt\)"):
        output_file(tmp_path / "run" / "model.pt", overwrite=True)
    assert output_file(tmp_path / "run" / "fields.png", owns=("fields.png",)).parent.is_dir()
    assert output_file(tmp_path / "run" / "new.png")  # a new file beside the run's is fine
    with pytest.raises(OutputPathError, match=r"expected a file name ending in \.npz"):
        output_file(tmp_path / "x.csv", "--out", suffixes=(".npz",))
    with pytest.raises(OutputPathError, match=r"is a directory; expected a file name"):
        output_file(tmp_path / "run")
    with pytest.raises(OutputPathError, match=r"is a file; expected a directory"):
        output_folder(tmp_path / "run" / "run.json")
    assert output_folder(tmp_path / "x" / "y").is_dir()
    assert isinstance(OutputPathError("m"), ValueError)  # the CLI's bad-input exit 2
    (tmp_path / "user").mkdir()  # a user's own bench.json is not bench's earlier result
    (tmp_path / "user" / "bench.json").write_text("mine")
    with pytest.raises(OutputPathError, match=r"holds bench\.json: its bench\.json is not one this command"):
        output_folder(tmp_path / "user", record="bench.json")
    (tmp_path / "user" / "bench.json").write_text('{"format": "pdeinv-bench"}')  # bench's own: replaced
    with pytest.raises(OutputPathError, match=r"holds this command's earlier results \(bench\.json\); pass "
                                              r"--overwrite"):
        output_folder(tmp_path / "user", record="bench.json")  # only with --overwrite
    replaced = output_folder(tmp_path / "user", record="bench.json", replace=True)
    assert replaced == (tmp_path / "user").resolve()


def test_a_problem_found_in_the_current_folder_is_stored_by_path(tmp_path, monkeypatch):
    """``pdeinv train mine`` in the folder of ``mine.py``, then ``pdeinv predict`` from elsewhere."""
    from pdeinv.io.runs import problem_spec
    from pdeinv.problem.definition import builtin_dir

    builtin = builtin_dir() / "heat_1d.py"
    (tmp_path / "mine.py").write_text(builtin.read_text())
    monkeypatch.chdir(tmp_path)
    assert problem_spec("mine") == str((tmp_path / "mine.py").resolve())
    assert problem_spec("heat_1d") == "heat_1d"  # a built-in stays a name
    shadow = tmp_path / "shadow"  # a heat_1d on PDEINV_PROBLEMS: a run of it must not reload the built-in
    shadow.mkdir()
    (shadow / "heat_1d.py").write_text(builtin.read_text())
    monkeypatch.setenv("PDEINV_PROBLEMS", str(shadow))
    assert problem_spec("heat_1d") == str((shadow / "heat_1d.py").resolve())
