"""Bad input meets a ValueError/FileNotFoundError that names the value and what is allowed."""

import numpy as np
import pytest
import torch
from exact import load

import pdeinv
from pdeinv.cli import main


@pytest.mark.parametrize("name, overrides, match", [
    ("heat_2d", dict(T=0), r"T=0.*> 0"),
    ("heat_2d", dict(T=-1.0), r"T=-1.0.*> 0"),
    ("heat_1d", dict(steps=0), r"steps=0.*integer >= 1"),
    ("heat_1d", dict(steps=2.5), r"steps=2.5.*integer"),
    ("heat_1d", dict(n=0), r"n=0.*integer >= 1"),
    ("heat_1d", dict(kappa=float("nan")), r"kappa=nan.*finite"),
    ("heat_1d", dict(kappa="abc"), r"kappa='abc' is not a number"),
    ("heat_1d", dict(scheme="rk4"), r"scheme='rk4'.*'be', 'cn'"),
    ("heat_1d", dict(backend="gpu"), r"backend='gpu'.*'auto', 'steps', 'modal'"),
    ("heat_1d", dict(element="P3"), r"element='P3'.*'P1', 'P2'"),
    ("heat_1d", dict(noise=-0.1), r"noise=-0.1.*>= 0"),
    ("heat_1d", dict(kapa=0.1), r"unknown setting.*'kapa'.*allowed: .*kappa"),
    ("wave_1d", dict(c=0), r"c=0.*> 0"),
    ("wave_1d", dict(kappa=0.1), r"unknown setting.*'kappa'"),
    ("heat_1d", dict(kappa=1e-320), r"kappa=1e-320 is out of range; expected a magnitude of at least 1e-150"),
])
def test_bad_overrides(name, overrides, match):
    with pytest.raises(ValueError, match=match):
        load(name, **overrides)


def test_string_overrides_are_coerced():
    p = load("heat_1d", n="16", kappa="0.02", steps="10")
    assert p.N == 15 and p.operator.kappa == 0.02 and p.operator.steps == 10


@pytest.mark.parametrize("name", ["heat_1d", "wave_1d"])
def test_operator_rejects_bad_arrays(name):
    op = load(name, n=8).operator
    with pytest.raises(ValueError, match=r"shape \(3, 8\); expected \(B, 7\)"):
        op.forward(np.zeros((3, 8)))
    with pytest.raises(ValueError, match=r"shape \(2, 3, 7\)"):
        op.adjoint(np.zeros((2, 3, 7)))
    bad = np.zeros((2, 7))
    bad[1, 4] = np.inf
    with pytest.raises(ValueError, match=r"NaN or Inf \(first at index \(1, 4\)\)"):
        op.forward(bad)
    with pytest.raises(ValueError, match="complex"):
        op.forward(np.zeros((1, 7), dtype=complex))
    with pytest.raises(ValueError, match="dtype"):
        op.forward(np.array([["a"] * 7]))


def test_unknown_problem_and_module_without_make(tmp_path):
    with pytest.raises(ValueError, match=r"unknown problem 'heat_4d'; available: .*heat_2d"):
        pdeinv.load_problem("heat_4d")
    with pytest.raises(FileNotFoundError, match="nope.py"):
        pdeinv.load_problem(tmp_path / "nope.py")
    mod = tmp_path / "nomake.py"
    mod.write_text("x = 1\n")
    with pytest.raises(ValueError, match="no function make"):
        pdeinv.load_problem(mod)


@pytest.mark.parametrize("source, match", [
    # a BaseException of the module's own was a traceback (only Exception and SystemExit were caught)
    ("class E(BaseException):\n    pass\ndef make(**kw):\n    raise E('odd')\n", r"line 4, in make: E: odd"),
    # SETTINGS as plain values (not (default, rule) pairs) failed inside resolve: "cannot unpack ... int"
    ("from pdeinv import settings as s\nSETTINGS = dict(n=16)\ndef make(**kw):\n"
     "    return s.resolve(SETTINGS, kw, 'rod')\n",
     r"line 4, in make: TypeError: settings of 'rod': 'n': 16 is not a \(default, rule\) pair"),
])
def test_a_module_that_fails_oddly_is_one_line(tmp_path, source, match):
    mod = tmp_path / "odd.py"
    mod.write_text(source)
    with pytest.raises(ValueError, match=r"problem module .*odd\.py', " + match) as err:
        pdeinv.load_problem(mod)
    assert "\n" not in str(err.value)


def test_a_folder_is_no_module(tmp_path, capsys):
    """A folder given as the problem was "does not exist"."""
    with pytest.raises(ValueError, match=r"is a directory; expected a \.py file"):
        pdeinv.load_problem(tmp_path)
    assert main(["demo", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_mesh_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.msh"):
        load("heat_2d", mesh=str(tmp_path / "missing.msh"))
    garbage = tmp_path / "garbage.vtu"
    garbage.write_text("this is not a mesh")
    with pytest.raises(ValueError, match="could not be read by meshio"):
        load("heat_2d", mesh=str(garbage))
    empty = tmp_path / "empty.msh"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match="could not be read"):
        load("heat_2d", mesh=str(empty))


def test_unsupported_cells(tmp_path):
    import meshio

    quads = tmp_path / "quads.vtu"
    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    meshio.write(quads, meshio.Mesh(pts, [("quad", np.array([[0, 1, 2, 3]]))]))
    with pytest.raises(ValueError, match=r"cell types \['quad'\]"):
        load("heat_2d", mesh=str(quads))
    mixed = tmp_path / "mixed.vtu"
    pts5 = np.vstack([pts, [[2, 0]]])
    meshio.write(mixed, meshio.Mesh(pts5, [("quad", np.array([[0, 1, 2, 3]])),
                                           ("triangle", np.array([[1, 4, 2]]))]))
    with pytest.raises(ValueError, match=r"\['quad', 'triangle'\]"):
        load("heat_2d", mesh=str(mixed))


def test_cli_reports_one_line_and_exit_code_2(capsys):
    assert main(["demo", "heat_1d", "--set", "T=-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "T=-1.0" in err[0] and "Traceback" not in err[0]
    assert main(["demo", "heat_1d", "--set", "oops"]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err


# -- the catalogue: one row per wrong input, through the Python API and through the CLI ------------
#
# Cases elsewhere: tests above (overrides, arrays, problems, meshes, cells), tests/test_sensors.py
# (sensor positions and layouts), tests/test_train.py (trainer settings, CLI method settings),
# tests/test_checkpoint.py (checkpoints of other runs, corrupt files) and tests/test_nan_guard.py.
# Output paths of every command (read-only folders, missing folders, a run's own files, inputs) are
# tests/test_output_paths.py; signals (SIGTERM, Ctrl-C during start-up) tests/test_signals.py; the
# names the entry points accept (train("heat_1d", "sip"), presets) tests/test_entry_points.py.
# The dt-above-stability-limit case (explicit leapfrog on wave scenes) is in tests/test_leapfrog.py;
# the implicit schemes (heat θ-scheme with θ >= ½, Newmark β = ¼) accept every dt.

@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Bad files of every kind, and a finished CLI run (heat_1d, n=16, hidden 8) to resume from."""
    import meshio

    d = tmp_path_factory.mktemp("bad")
    (d / "file.txt").write_text("a file, not a folder")
    (d / "nomake.py").write_text("x = 1\n")
    (d / "wrongtype.py").write_text("def make(**kw):\n    return 42\n")
    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    meshio.write(d / "ok.msh", meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2], [0, 2, 3]]))]),
                 file_format="gmsh22", binary=False)
    text = (d / "ok.msh").read_bytes()
    (d / "truncated.msh").write_bytes(text[: len(text) // 2])
    (d / "empty.msh").write_bytes(b"")
    cube = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    meshio.write(d / "tet.vtu", meshio.Mesh(cube, [("tetra", np.array([[0, 1, 2, 3]]))]))
    meshio.write(d / "past.vtu", meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2], [0, 2, 7]]))]))
    meshio.write(d / "quads.vtu", meshio.Mesh(pts, [("quad", np.array([[0, 1, 2, 3]]))]))
    assert main(["train", "--prior-fit", "0", "heat_1d", *SMALL[:-4], "--threads", "1", "--steps", "2",
                 "--checkpoint-every", "1", "--out", str(d / "run")]) == 0
    (d / "corrupt").mkdir()
    good = (d / "run" / "checkpoint.pt").read_bytes()
    (d / "corrupt" / "checkpoint.pt").write_bytes(good[: len(good) // 3])
    (d / "corrupt" / ".pdeinv-run").write_bytes((d / "run" / ".pdeinv-run").read_bytes())  # a run's folder
    return d


#: a small, valid training run; each CLI row changes one thing
SMALL = ["--set", "n=16", "--set", "steps=10", "--hidden", "8", "--n-train", "16", "--n-test", "8",
         "--batch-size", "8", "--steps", "3", "--threads", "1"]
OPTIONS = dict(zip(SMALL[4::2], SMALL[5::2]))  # --hidden 8, --n-train 16, ...

#: (id, argv after ``pdeinv train``, the message (regex)); "{d}" is the folder of bad files
CLI = [
    ("unknown-problem", ["heat_4d"], r"unknown problem 'heat_4d'; available: .*heat_1d"),
    ("missing-module", ["{d}/nope.py"], r"problem module '.*nope\.py' does not exist"),
    ("module-without-make", ["{d}/nomake.py"], r"has no function make"),
    ("make-returns-wrong-type", ["{d}/wrongtype.py"], r"make\(\) returned int; expected a pdeinv\.Problem"),
    ("unknown-override", ["heat_1d", "--set", "kapa=1"], r"unknown setting.*'kapa'.*allowed:.*kappa"),
    ("override-not-a-number", ["heat_1d", "--set", "T=soon"], r"T='soon' is not a number"),
    ("override-not-key-value", ["heat_1d", "--set", "kappa"], r"--set 'kappa' is not KEY=VALUE"),
    ("T-negative", ["heat_1d", "--set", "T=-1"], r"T=-1\.0 is not allowed; expected a number > 0"),
    ("T-zero", ["wave_1d", "--set", "T=0"], r"T=0\.0 is not allowed"),
    ("steps-zero", ["heat_1d", "--set", "steps=0"], r"steps=0 is not allowed; expected an integer >= 1"),
    ("n-negative", ["heat_1d", "--set", "n=-4"], r"n=-4 is not allowed"),
    ("kappa-zero", ["heat_1d", "--set", "kappa=0"], r"kappa=0\.0 is not allowed; expected a number > 0"),
    ("kappa-nan", ["heat_1d", "--set", "kappa=nan"], r"kappa=nan is not allowed; expected a finite"),
    ("T-inf", ["heat_1d", "--set", "T=inf"], r"T=inf is not allowed; expected a finite"),
    ("c-negative", ["wave_1d", "--set", "c=-1"], r"c=-1\.0 is not allowed"),
    ("noise-negative", ["heat_1d", "--set", "noise=-0.1"], r"noise=-0\.1 is not allowed; expected .*>= 0"),
    ("mesh-missing", ["heat_2d", "--set", "mesh={d}/missing.msh"], r"missing\.msh"),
    ("mesh-empty", ["heat_2d", "--set", "mesh={d}/empty.msh"], r"could not be read"),
    ("mesh-truncated", ["heat_2d", "--set", "mesh={d}/truncated.msh"], r"could not be read"),
    ("mesh-corrupt", ["heat_2d", "--set", "mesh={d}/file.txt"], r"could not be read"),
    ("mesh-quads", ["heat_2d", "--set", "mesh={d}/quads.vtu"], r"cell types \['quad'\]"),
    ("mesh-3d-for-2d", ["heat_2d", "--set", "mesh={d}/tet.vtu"], r"holds a 3-D mesh \(tetra cells\); "
                                                                  r"this problem expects a 2-D mesh"),
    ("mesh-2d-for-3d", ["heat_3d", "--set", "mesh={d}/ok.msh"], r"holds a 2-D mesh .* expects a 3-D mesh"),
    ("mesh-cells-past-nodes", ["heat_2d", "--set", "mesh={d}/past.vtu"], r"refers to node 7, but the file "
                                                                         r"has 4 nodes"),
    ("sensor-outside", ["heat_sensors_2d", "--set", "sensors=[[0.5, 0.5], [1.5, 0.5]]", "--set",
                        "record_every=1"], r"outside the mesh.*sensor 1 at \[1\.5, 0\.5\]"),
    ("batch-above-data", ["heat_1d", "--batch-size", "64"],
     r"--batch-size 64 is larger than --n-train 16; expected --batch-size <= 16"),
    ("batch-default-n-train", ["heat_1d", "--batch-size", "1000000000", "--n-train", "1024"],
     r"--batch-size 1000000000 is larger than --n-train 1024; expected"),
    ("lr-nan", ["heat_1d", "--lr", "nan"], r"--lr nan is not allowed; expected a finite number"),
    ("lr-negative", ["heat_1d", "--method", "sip", "--lr=-1e-3"], r"--lr -0\.001 is not allowed"),
    ("max-failures-zero", ["heat_1d", "--max-failures", "0"], r"--max-failures 0 is not allowed"),
    ("checkpoint-every-negative", ["heat_1d", "--checkpoint-every", "-1"], r"--checkpoint-every -1"),
    ("threads-zero", ["heat_1d", "--threads", "0"], r"--threads 0 is not allowed"),
    ("n-train-zero", ["heat_1d", "--n-train", "0"], r"--n-train 0 is not allowed; expected an integer >= 2"),
    ("n-test-zero", ["heat_1d", "--n-test", "0"], r"--n-test 0 is not allowed"),
    ("hidden-empty", ["heat_1d", "--hidden", ""], r"--hidden '' is not a comma-separated list"),
    ("out-empty", ["heat_1d", "--out", ""], r"--out '' is empty; expected a path"),
    ("out-is-a-file", ["heat_1d", "--out", "{d}/file.txt"], r"is a file; expected a directory"),
    ("out-under-a-file", ["heat_1d", "--out", "{d}/file.txt/sub"],
     r"error: --out '.*file\.txt/sub' is not a writable directory \(a file is in the way: '.*file\.txt'\)"),
    ("out-not-writable", ["heat_1d", "--out", "/proc/pdeinv-test"], r"not a writable directory"),
    ("out-has-a-run", ["heat_1d", "--out", "{d}/run"], r"metrics\.json exists; .*--resume.*--overwrite"),
    ("resume-nothing", ["heat_1d", "--resume"], r"no checkpoint at '.*checkpoint\.pt' to resume from"),
    ("resume-corrupt", ["heat_1d", "--resume", "--out", "{d}/corrupt"], r"corrupt or not a pdeinv"),
    ("resume-other-problem", ["wave_1d", "--resume", "--out", "{d}/run"],
     r"is of problem 'heat_1d', this run is 'wave_1d'"),
    ("resume-other-settings", ["heat_1d", "--set", "kappa=0.02", "--resume", "--out", "{d}/run"],
     r"kappa=0\.01 \(checkpoint\) vs 0\.02 \(this run\)"),
    ("resume-other-network", ["heat_1d", "--hidden", "16", "--resume", "--out", "{d}/run"],
     r"holds network MLP \(.*\(8, 15\).*this run's network is MLP \(.*\(16, 15\)"),
    ("resume-other-method", ["heat_1d", "--method", "adam", "--resume", "--out", "{d}/run"],
     r"written with rule 'sip'; this run has 'adam'"),
    ("resume-without-checkpoints", ["heat_1d", "--resume", "--checkpoint-every", "0"], r"--resume needs"),
]


def _argv(argv, d, tmp_path):
    """``argv`` completed with SMALL's options and (1-D scenes) settings that it does not set itself."""
    argv = [a.replace("{d}", str(d)) for a in argv]
    extra = [x for k, v in OPTIONS.items() if k not in argv for x in (k, v)]
    if argv[0] in ("heat_1d", "wave_1d"):
        extra += [x for kv in ("n=16", "steps=10") if not any(a.startswith(kv[:2]) for a in argv)
                  for x in ("--set", kv)]
    out = [] if "--out" in argv else ["--out", str(tmp_path / "out")]
    return ["train", "--prior-fit", "0", *argv, *extra, *out]


@pytest.mark.parametrize("argv, match", [pytest.param(a, m, id=i) for i, a, m in CLI])
def test_cli_bad_input_exits_2_with_one_line(files, tmp_path, capsys, argv, match):
    import re

    before = {p: p.read_bytes() for p in files.rglob("*") if p.is_file()}
    code = main(_argv(argv, files, tmp_path))
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("pdeinv train: error: ") and "Traceback" not in err
    assert re.search(match, err), err
    after = {p: p.read_bytes() for p in files.rglob("*") if p.is_file()}
    assert after == before  # nothing already written is lost, truncated or left behind


#: (id, call, exception, message); the Python API raises what the CLI reports
API = [
    ("kappa-negative", lambda: load("heat_1d", n=8, kappa=-1.0), ValueError, r"kappa=-1\.0 is not allowed"),
    ("c-string-nan", lambda: load("wave_1d", n=8, c="nan"), ValueError, r"c=nan is not allowed"),
    ("relative-error-nan", lambda: load("heat_1d", n=8).relative_error(np.full((2, 7), np.nan),
                                                                       np.ones((2, 7))),
     ValueError, r"xhat contains NaN or Inf"),
    ("relative-error-shape", lambda: load("heat_1d", n=8).relative_error(np.ones((2, 6)), np.ones((2, 7))),
     ValueError, r"xhat has shape \(2, 6\); expected \(B, 7\)"),
    ("adjoint-inf", lambda: load("wave_1d", n=8).operator.adjoint(np.full((1, 7), np.inf)), ValueError,
     r"R contains NaN or Inf"),
    ("operator-torch-input", lambda: load("heat_1d", n=8).operator.forward(torch.zeros(1, 7)), ValueError,
     r"torch tensor; operators take numpy arrays"),
    ("inverse-nan", lambda: load("heat_1d", n=8).inverse(np.full((1, 7), np.nan), np.zeros((1, 7))),
     ValueError, r"NaN or Inf"),
    ("sample-zero", lambda: load("heat_1d", n=8).sample(0), ValueError, r"n=0 is not allowed"),
    ("hig-over-budget", lambda: _hig_step(max_jacobian_gb=1e-9, route="svd"), ValueError,
     r"HIG Jacobian .*GB"),
    ("hig-tau-one", lambda: pdeinv.HIG(tau=1.0), ValueError,
     r"tau=1\.0 is not allowed; expected 0 <= tau < 1"),
    ("sip-eta-zero", lambda: pdeinv.SIP(eta=0), ValueError, r"eta=0 is not allowed"),
    # accepted silently by the rule before, failing at its first step or never
    ("sip-optimizer-name", lambda: pdeinv.SIP(optimizer="adam"), TypeError,
     r"optimizer='adam' is str; expected a factory params -> torch\.optim\.Optimizer"),
    ("gd-optimizer-none", lambda: pdeinv.GD(optimizer=None), TypeError, r"optimizer=None is NoneType"),
    ("sip-inverse-name", lambda: pdeinv.SIP(inverse="tikhonov"), TypeError,
     r"inverse='tikhonov' is str; expected None"),
    ("hig-seed-negative", lambda: pdeinv.HIG(seed=-1), ValueError, r"seed=-1 is not allowed"),
    ("hig-exponent-nan", lambda: pdeinv.HIG(exponent=float("nan")), ValueError,
     r"exponent=nan is not allowed; expected a finite number"),
    ("hig-cond-zero", lambda: pdeinv.HIG(gram_cond_max=0), ValueError, r"gram_cond_max=0 .*>= 1"),
    ("hig-normalize-int", lambda: pdeinv.HIG(normalize=1), TypeError, r"normalize=1 is int"),
    ("hig-sum-over", lambda: pdeinv.HIG(sum_over=5), TypeError, r"sum_over=5 is int"),
    ("trainer-max-failures", lambda: _trainer(max_failures=0), ValueError, r"max_failures=0 is not allowed"),
    ("trainer-step-factor", lambda: _trainer(step_factor=2.0), ValueError, r"step_factor=2\.0 .*<= 1"),
    ("trainer-resume-no-checkpoint", lambda: _trainer(resume=True), ValueError,
     r"resume=True needs checkpoint="),
    ("checkpoint-every-zero", lambda: pdeinv.Checkpoint("c.pt", every=0), ValueError,
     r"checkpoint every=0 is not allowed"),
    # a user's file as the checkpoint path was replaced by the first save
    ("checkpoint-a-users-file", lambda: pdeinv.Checkpoint(__file__), ValueError,
     r"test_bad_input\.py' exists and is corrupt or not a pdeinv checkpoint: saving there would"),
    ("batch-above-data", lambda: _trainer(batch_size=9, n_train=8), ValueError,
     r"batch_size=9 is larger than n_train=8"),
    ("batch-above-data-rows",
     lambda: _trainer(batch_size=40, n_test=8, data=load("heat_1d", n=8).sample(40)[1]), ValueError,
     r"batch_size=40 \(--batch-size\) is larger than the 32 training rows of data \(its rows less "
     r"n_test=8 \(--n-test\)"),
    # typed entry points (issue 36): the kind of object is a TypeError, its value a ValueError
    ("train-args-swapped", lambda: pdeinv.Trainer(pdeinv.SIP(), _heat(), steps=1, prior=None), TypeError,
     r"problem is an update rule \(SIP\); expected a pdeinv\.Problem.*swapped\?"),
    ("train-rule-unknown-name", lambda: pdeinv.Trainer(_heat(), "sipp", steps=1, prior=None), ValueError,
     r"rule='sipp' is not a method name; expected one of 'gd', 'adam', 'sip'"),
    ("train-rule-is-a-class", lambda: pdeinv.Trainer(_heat(), pdeinv.SIP, steps=1, prior=None), TypeError,
     r"rule=SIP is a class; expected an instance: pdeinv\.SIP\(\)"),
    ("train-rule-is-a-number", lambda: pdeinv.Trainer(_heat(), 3, steps=1, prior=None), TypeError,
     r"rule=3 is int; expected an update rule .*no init or update method"),
    ("train-problem-none", lambda: pdeinv.Trainer(None, pdeinv.SIP(), steps=1, prior=None), TypeError,
     r"problem=None is NoneType; expected a pdeinv\.Problem"),
    ("train-problem-unknown-name", lambda: pdeinv.Trainer("heat_4d", pdeinv.SIP(), steps=1,
                                                          prior=None), ValueError,
     r"unknown problem 'heat_4d'"),
    ("train-model-is-a-result", lambda: pdeinv.Trainer(_heat(), pdeinv.SIP(), _result(), steps=1,
                                                       prior=None), TypeError,
     r"model is a training Result; expected its network: pass result\.model"),
    ("train-model-is-an-array", lambda: pdeinv.Trainer(_heat(), pdeinv.SIP(), np.zeros((2, 7)), steps=1,
                                                       prior=None),
     TypeError, r"model is an array of shape \(2, 7\); expected a torch\.nn\.Module"),
    ("train-seed-negative", lambda: _trainer(seed=-1), ValueError,
     r"seed=-1 is not allowed; expected an integer from 0 to 4294967295"),
    ("train-seed-float", lambda: _trainer(seed=1.5), ValueError, r"seed=1\.5 is not allowed"),
    ("train-stop-unknown-name", lambda: _trainer(stop="early"), ValueError,
     r"stop='early' is not allowed; expected one of 'auto', 'discrepancy', 'plateau', 'none'"),
    ("train-stop-is-a-class", lambda: _trainer(stop=pdeinv.DiscrepancyStop), TypeError,
     r"stop=.* is a class: call it, DiscrepancyStop\(\)"),
    ("train-checkpoint-number", lambda: _trainer(checkpoint=5), TypeError,
     r"checkpoint=5 is int; expected pdeinv\.Checkpoint\(path, every=k\) or a path"),
    ("train-callbacks-not-callable", lambda: _trainer(callbacks=[1]), TypeError,
     r"callbacks\[0\]=1 is not callable"),
    ("train-dtype-int", lambda: _trainer(dtype=torch.int64), TypeError, r"dtype=torch\.int64 is not allowed"),
    ("train-progress-string", lambda: _trainer(progress="yes"), TypeError,
     r"progress='yes' is str; expected True, False or None"),
    ("sgd-lr-zero", lambda: pdeinv.sgd(0), ValueError, r"sgd lr=0 is not allowed; expected a number > 0"),
    ("adam-lr-negative", lambda: pdeinv.adam(-1), ValueError, r"adam lr=-1 is not allowed"),
    ("adam-lr-nan", lambda: pdeinv.adam(float("nan")), ValueError, r"adam lr=nan is not allowed; .*finite"),
    ("load-problem-none", lambda: pdeinv.load_problem(None), TypeError,
     r"name_or_path=None is not allowed; expected a problem name .*pdeinv\.available\(\)"),
    ("load-problem-a-problem", lambda: pdeinv.load_problem(_heat()), TypeError,
     r"name_or_path is already a Problem \('heat_1d'\)"),
    ("predict-result", lambda: pdeinv.io.export.predict(_result(), np.zeros((2, 7))), TypeError,
     r"model is a training Result; expected its network: pass result\.model"),
    ("predict-swapped", lambda: pdeinv.io.export.predict(np.zeros((2, 7)), _result().model), TypeError,
     r"model is an array of shape \(2, 7\).*swapped"),
    ("predict-wrong-width", lambda: pdeinv.io.export.predict(_result().model, np.zeros((2, 5))), ValueError,
     r"y has shape \(2, 5\); the network does not take 5 observations per row"),
    ("predict-wrong-width-problem",
     lambda: pdeinv.io.export.predict(_result().model, np.zeros((2, 5)), _heat()), ValueError,
     r"y has shape \(2, 5\); expected \(B, 7\) or \(7,\)"),
    ("predict-nan", lambda: pdeinv.io.export.predict(_result().model, np.full((2, 7), np.nan)), ValueError,
     r"y contains NaN or Inf"),
    ("plot-prediction-widths", lambda: pdeinv.io.plots.plot_prediction(_heat(), np.zeros((2, 7)),
                                                                       np.zeros((2, 3))),
     ValueError, r"x_pred has shape \(2, 3\); expected \(B, 7\)"),
    ("plot-prediction-samples", lambda: pdeinv.io.plots.plot_prediction(_heat(), np.zeros((2, 7)),
                                                                        np.zeros((1, 7))),
     ValueError, r"x_true has shape \(2, 7\) but x_pred has \(1, 7\)"),
    ("save-run-result", lambda: pdeinv.save_run("unused", "heat_1d", model=_result()), TypeError,
     r"model is a training Result; expected its network: pass result\.model"),
    ("save-run-no-model", lambda: pdeinv.save_run("unused", "heat_1d"), TypeError,
     r"model=None is NoneType; expected a torch\.nn\.Module"),
    ("save-run-network-kind", lambda: pdeinv.save_run("unused", "heat_1d", {}, {"kind": "cnn"},
                                                      _result().model),
     ValueError, r"network_spec=\{'kind': 'cnn'\} is not allowed; expected .*'default'"),
    ("save-run-read-only", lambda: pdeinv.save_run("/proc/pdeinv-test", "heat_1d", model=_result().model),
     ValueError, r"out '/proc/pdeinv-test' is not a writable directory"),
    # one line naming the kinds (a Result's or a network's repr was many lines)
    ("save-run-swapped", lambda: pdeinv.save_run("unused", _result()), TypeError,
     r"^problem is a training Result; expected the problem's name .*model=result\.model"),
    ("save-run-swapped-out", lambda: pdeinv.save_run(_result(), "unused"), TypeError,
     r"^out is a training Result; expected the run's folder"),
    ("save-run-network-as-problem", lambda: pdeinv.save_run("unused", _result().model), TypeError,
     r"^problem is a network \(\w+\); expected the problem's name[^\n]*$"),
    ("n-train-one", lambda: _trainer(n_train=1), ValueError,
     r"n_train=1 is not allowed; expected an integer >= 2"),
    ("data-x-without-data", lambda: _trainer(data_x=np.zeros((4, 7))), ValueError,
     r"data_x= was given without data="),
    ("sample-seed-negative", lambda: _heat().sample(2, seed=-1), ValueError,
     r"seed=-1 is not allowed; expected an integer from 0 to 4294967295"),
    ("sample-seed-float", lambda: _heat().sample(2, seed=1.5), ValueError, r"seed=1\.5 is not allowed"),
    ("sip-name-int", lambda: pdeinv.SIP(name=3), TypeError, r"name=3 is int; expected a non-empty str"),
    ("gd-name-blank", lambda: pdeinv.GD(name=" "), ValueError,
     r"name=' ' is not allowed; expected a non-empty"),
    ("hig-name-none", lambda: pdeinv.HIG(name=None), TypeError,
     r"name=None is NoneType; expected a non-empty"),
]


def _heat():
    return load("heat_1d", n=8)


_RESULT = []


def _result():
    """One tiny finished run, shared by the rows that need a Result."""
    if not _RESULT:
        _RESULT.append(pdeinv.train(_heat(), "sip", n_train=8, n_test=4, steps=1, progress=False, prior=None))
    return _RESULT[0]


def _trainer(**kw):
    return pdeinv.Trainer(load("heat_1d", n=8), pdeinv.GD(), steps=1, **{"prior": None, **kw})


def _hig_step(**kw):
    p = load("heat_1d", n=8)
    model = p.model()
    rule = pdeinv.HIG(**kw)
    return rule.step(rule.init(p, model), model, torch.zeros(4, p.operator.n_out))


@pytest.mark.parametrize("call, exc, match", [pytest.param(c, e, m, id=i) for i, c, e, m in API])
def test_api_bad_input_names_the_value(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


def test_a_failing_run_keeps_what_was_written(files, tmp_path, capsys):
    """--overwrite / --resume runs that fail leave metrics.json and the checkpoint byte for byte."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(files / "run", run)
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    for extra in (["--overwrite", "--set", "kappa=-1"], ["--resume", "--hidden", "4"],
                  ["--overwrite", "--method", "hig", "--eta=-1"]):
        flags = {a for a in extra if a.startswith("--") and a != "--set"}  # the base gives way
        base = [a for i, a in enumerate(SMALL) if a not in flags and (i == 0 or SMALL[i - 1] not in flags)]
        assert main(["train", "--prior-fit", "0", "heat_1d", *base, "--out", str(run), *extra]) == 2
    capsys.readouterr()
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before


@pytest.mark.parametrize("damage, match", [
    # a run.json of a later pdeinv was read as if it were this one's (predict exited 0)
    (lambda run: (run / "run.json").write_text((run / "run.json").read_text().replace(
        '"version": 1', '"version": 999')), r"run\.json has version 999; this pdeinv reads run records of"),
    # a model.pt that is no torch file printed the first 120 characters of torch's unpickling essay
    (lambda run: (run / "model.pt").write_bytes(b"garbage"),
     r"model\.pt cannot be read as a torch state dict \(damaged, or not a file pdeinv wrote\)"),
    # another run's model of the same shape loaded and predicted that run's answers (exit 0)
    (lambda run: torch.save({k: v + 1 for k, v in torch.load(run / "model.pt").items()}, run / "model.pt"),
     r"model\.pt is not the model its run\.json was written with"),
], ids=["version-999", "model-garbage", "model-swapped"])
def test_a_damaged_run_is_refused_in_one_line(files, tmp_path, capsys, damage, match):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(files / "run", run)
    damage(run)
    with pytest.raises(ValueError, match=match):
        pdeinv.load_run(run)
    x, y = pdeinv.load_problem("heat_1d", n=16, steps=10).sample(2, seed=0)
    np.savez(tmp_path / "obs.npz", y=y)
    obs, out = str(tmp_path / "obs.npz"), str(tmp_path / "p.npz")
    assert main(["predict", str(run), "--data", obs, "--out", out]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and not (tmp_path / "p.npz").exists()
