"""Nothing of the user's is touched (issue 48, item 3): every output path is resolved (``..`` through a
folder that does not exist yet, symbolic links) before any check; ``train --overwrite`` replaces only a
folder pdeinv marked as its run, and only the files pdeinv wrote; any other non-empty folder is refused,
naming what is in it; a single-file writer (``predict --out/--vtu``, ``classical --out``, ``show --png``)
replaces an existing file only with ``--overwrite``."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.io.runs import OUTPUTS
from pdeinv.util.outpaths import RUN_MARKER, OutputPathError, is_run_folder, output_file, run_folder

pytestmark = pytest.mark.usefixtures("one_thread")

SMALL = ["--set", "n=16", "--steps", "2", "--prior-fit", "0", "-q", "--threads", "1"]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A finished run with fields.vtu/png, and observations of its problem."""
    d = tmp_path_factory.mktemp("made")
    assert main(["train", "heat_1d", *SMALL, "--export-samples", "1", "--out", str(d / "run")]) == 0
    x, y = pdeinv.load_problem("heat_1d", n=16).sample(4, seed=5)
    np.savez(d / "obs.npz", x=x, y=y)
    return d


@pytest.fixture
def here(made, tmp_path, monkeypatch):
    """A copy of the run in ``runs/h1`` and of the observations, in the current folder ``tmp_path``."""
    shutil.copytree(made / "run", tmp_path / "runs" / "h1")
    shutil.copy(made / "obs.npz", tmp_path / "obs.npz")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def snapshot(folder):
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def refused(capsys, argv, *needles, folder):
    """``argv`` exits 2 with one line holding every needle, and changes no file under ``folder``."""
    before = snapshot(folder)
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    assert snapshot(folder) == before
    return err


def test_a_dot_dot_through_a_folder_not_made_yet_reaches_the_run_and_is_refused(here, capsys):
    refused(capsys, ["train", "heat_1d", *SMALL, "--out", "out/new/../../runs/h1"],
            "metrics.json exists", str(here / "runs" / "h1"), folder=here)
    assert not (here / "out").exists()  # nothing created on the way to a refusal


def test_a_link_to_a_run_is_the_run(here, capsys):
    os.symlink(here / "runs" / "h1", here / "link")
    refused(capsys, ["train", "heat_1d", *SMALL, "--out", "link"], "metrics.json exists", folder=here)


def test_a_users_folder_is_refused_even_with_overwrite_naming_what_it_holds(here, capsys):
    mine = here / "mine"
    mine.mkdir()
    (mine / "metrics.json").write_text('{"mine": 1}')
    (mine / "history.csv").write_text("a,b\n1,2\n")
    for extra in ([], ["--overwrite"]):
        err = refused(capsys, ["train", "heat_1d", *SMALL, "--out", "mine", *extra],
                      "history.csv, metrics.json", "not a pdeinv run folder", folder=here)
        assert "--overwrite" in err  # says what --overwrite can replace


def test_any_other_non_empty_folder_is_refused(here, capsys):
    (here / "notes").mkdir()
    (here / "notes" / "thesis.tex").write_text("mine")
    refused(capsys, ["train", "heat_1d", *SMALL, "--out", "notes"], "thesis.tex", folder=here)


def test_overwrite_replaces_only_the_runs_own_files(here, capsys):
    run = here / "runs" / "h1"
    (run / "notes.txt").write_text("mine")
    (run / "metrics.json.bak").write_text("mine too")
    assert main(["train", "heat_1d", *SMALL, "--export-samples", "0", "--out", "out/new/../../runs/h1",
                 "--overwrite"]) == 0
    capsys.readouterr()
    names = {p.name for p in run.iterdir()}
    assert {"notes.txt", "metrics.json.bak", RUN_MARKER, "metrics.json"} <= names
    assert not {"fields.vtu", "fields.png"} & names  # the previous run's, not written by this one
    assert (run / "notes.txt").read_text() == "mine"


def test_a_run_written_before_the_marker_is_still_a_run(here, capsys):
    run = here / "runs" / "h1"
    (run / RUN_MARKER).unlink()
    assert is_run_folder(run)  # run.json with pdeinv's own format key
    assert main(["train", "heat_1d", *SMALL, "--out", str(run), "--overwrite"]) == 0
    capsys.readouterr()
    (run / RUN_MARKER).unlink()
    (run / "run.json").write_text(json.dumps({"format": "someone-else"}))
    assert not is_run_folder(run)


def test_an_empty_folder_or_a_stale_lock_is_fine(here, capsys):
    (here / "empty").mkdir()
    (here / "locked").mkdir()
    (here / "locked" / ".lock").write_text("12345")
    for name in ("empty", "locked"):
        assert main(["train", "heat_1d", *SMALL, "--export-samples", "0", "--out", name]) == 0
        assert (here / name / RUN_MARKER).is_file()
    capsys.readouterr()


@pytest.mark.parametrize("argv, needle", [
    (["classical", "heat_1d", "--set", "n=16", "--data", "obs.npz",
      "--out", "x/new/../../runs/h1/metrics.json"],
     "one of a run's own files (metrics.json)"),
    (["predict", "runs/h1", "--data", "obs.npz", "--out", "p.npz", "--vtu", "x/new/../../runs/h1/fields.vtu"],
     "one of a run's own files (fields.vtu)"),
    (["show", "runs/h1", "--png", "x/new/../../runs/h1/training.png"], "one of a run's own files"),
    (["predict", "runs/h1", "--data", "x/new/../../obs.npz", "--out", "obs.npz"], "same file as --data"),
], ids=["classical", "predict-vtu", "show-png", "predict-its-data"])
def test_single_file_writers_resolve_before_checking(here, capsys, argv, needle):
    refused(capsys, argv, needle, folder=here)
    assert not (here / "x").exists()


@pytest.mark.parametrize("argv", [
    ["show", "runs/h1", "--png", "{f}.png"],
    ["predict", "runs/h1", "--data", "obs.npz", "--out", "{f}.npz"],
    ["predict", "runs/h1", "--data", "obs.npz", "--out", "p.npz", "--vtu", "{f}.vtu"],
    ["classical", "heat_1d", "--set", "n=16", "--data", "obs.npz", "--out", "{f}.json"],
], ids=["show", "predict-out", "predict-vtu", "classical"])
def test_an_existing_file_is_replaced_only_with_overwrite(here, capsys, argv):
    target = argv[-1].format(f="mine")
    (here / target).write_text("a user's file")
    argv = [a.format(f="mine") for a in argv]
    refused(capsys, argv, f"'{target}' exists", "--overwrite", folder=here)
    os.symlink(here / target, here / f"link{target}")
    link = [*argv[:-1], f"link{target}"]
    refused(capsys, link, "exists", folder=here)  # through a link: the same file
    assert main([*argv, "--overwrite"]) in (0, 3), capsys.readouterr().err
    assert (here / target).read_bytes() != b"a user's file"


def test_show_redraws_its_own_picture_without_overwrite(here, capsys):
    assert main(["show", "runs/h1"]) == 0
    capsys.readouterr()


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_show_never_redraws_another_runs_picture(here, capsys, overwrite):
    shutil.copytree(here / "runs" / "h1", here / "runs" / "other")
    argv = ["show", "runs/h1", "--png", "runs/other/fields.png", *overwrite]
    refused(capsys, argv, "one of a run's own", folder=here)


def test_a_damaged_fields_file_is_one_line(here, capsys):
    (here / "runs" / "h1" / "fields.vtu").write_bytes(b"<VTKFile garbage")
    refused(capsys, ["show", "runs/h1", "--png", "new.png"], "fields file", "cannot be read",
            folder=here / "runs")


def test_not_a_regular_file_is_refused(here):
    os.mkfifo(here / "pipe.png")
    with pytest.raises(OutputPathError, match="is not a regular file"):
        output_file(here / "pipe.png", "--png", overwrite=True)


def test_the_policy_resolves_and_names_both_paths(here):
    with pytest.raises(OutputPathError, match=r"'out/new/\.\./\.\./runs/h1' \(= '.*/runs/h1'\)"):
        run_folder("out/new/../../runs/h1", "--out", outputs=OUTPUTS)
    assert run_folder("out/new/../../runs/h1", "--out", replace=True, outputs=OUTPUTS) == \
        (here / "runs" / "h1").resolve()
    assert not (here / "out").exists()
