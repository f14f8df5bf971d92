"""What a new user hit (issue 17, parts 2, 3 and 6): size guards, defaults, messages, the Python API.

The CLI rows extend the bad-input catalogue of tests/test_bad_input.py: exit 2 and one line for
bad input (a memory estimate above the budget included), never a traceback.
"""

import json
import re
import subprocess
import sys

import meshio
import numpy as np
import pytest
import torch

import pdeinv
from pdeinv.cli import main
from pdeinv.methods.base import make_optimizer, optimizer_hyperparameters
from pdeinv.methods.presets import make_rule

SMALL = ["--set", "n=16", "--set", "steps=10", "--hidden", "8", "--n-train", "16", "--n-test", "8",
         "--batch-size", "8", "--steps", "3", "--threads", "1", "--export-samples", "0"]


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    write = lambda name, p, t: meshio.write(d / name, meshio.Mesh(p, [("triangle", t)]),  # noqa: E731
                                            file_format="gmsh22", binary=False)
    write("flat.msh", np.r_[pts, [[0.5, 0.5]]], np.r_[tri, [[0, 2, 4]]])  # 4 on the diagonal 0-2
    write("nan.msh", np.r_[pts[:3], [[np.nan, 1.0]]], tri)
    write("dup.msh", np.r_[pts, [[1.0, 1.0]]], np.array([[0, 1, 2], [0, 4, 3]]))  # node 4 = node 2
    (d / "module.txt").write_text("def make(**kw):\n    return 1\n")
    return d


#: (id, argv after ``pdeinv train`` (SMALL appended unless it sets the option), message regex)
CLI = [
    ("mesh-n-huge", ["heat_2d", "--set", "n=20000"], r"n=20000 .* needs about \d.* GB .* budget of"),
    ("plate-refine-8", ["heat_plate", "--set", "refine=8"], r"refine=8 .* GB .*smaller refine"),
    ("sensors-million", ["wave_sensors_2d", "--set", "sensors=1000000", "--max-memory-gb", "1"],
     r"1000000 sensors needs about 2 GB .* budget of 1 GB"),
    ("n-train-huge", ["heat_1d", "--n-train", "100000000"], r"training heat_1d .* GB .*--n-train"),
    ("hidden-huge", ["heat_1d", "--hidden", "100000,100000"], r"1e\+10 parameters.* GB"),
    ("small-budget", ["heat_1d", "--max-memory-gb", "1e-6"], r"budget of 1e-06 GB \(--max-memory-gb\)"),
    ("budget-negative", ["heat_1d", "--max-memory-gb=-1"], r"--max-memory-gb -1\.0 is not allowed"),
    ("hig-mlp-full-batch", ["heat_1d", "--method", "hig", "--hidden", "64", "--n-train", "1024",
                            "--batch-size", "1024"],  # the SVD route (n=64, (16,): 64 s), unrefused
     r"HIG on heat_1d would take about .* s per step \(Jacobian \d+ x 1999,.*--hidden 16 --batch-size 1"),
    ("mesh-zero-area", ["heat_2d", "--set", "mesh={d}/flat.msh"], r"cell 2 .* has zero size"),
    ("mesh-nan", ["heat_2d", "--set", "mesh={d}/nan.msh"], r"node 3 has coordinates \[nan, 1\.0\]"),
    ("mesh-duplicated", ["heat_2d", "--set", "mesh={d}/dup.msh"], r"nodes 2, 4 coincide at \[1\.0, 1\.0\]"),
    ("mesh-directory", ["heat_2d", "--set", "mesh={d}"], r"mesh='.*' is a directory; expected a file"),
    ("problem-not-py", ["{d}/module.txt"], r"is not a \.py file"),
    ("seed-negative", ["heat_1d", "--seed", "-1"], r"--seed -1 is not allowed; expected an integer from 0"),
    ("seed-overflow", ["heat_1d", "--seed", str(2**70)], r"--seed 1180591620717411303424 is not allowed"),
    ("n-fraction", ["heat_2d", "--set", "n=1.5"], r"n=1\.5 is not allowed \(1\.5 is not a whole number\)"),
    ("kappa-overflow", ["heat_1d", "--set", "kappa=1e308"],
     r"kappa='1e308' is out of range; expected a number of magnitude at most 1e\+150"),
]


@pytest.mark.parametrize("argv, match", [pytest.param(a, m, id=i) for i, a, m in CLI])
def test_cli_bad_input_exits_2_with_one_line(meshes, tmp_path, capsys, argv, match):
    argv = [a.replace("{d}", str(meshes)) for a in argv]
    extra = [x for k, v in zip(SMALL[4::2], SMALL[5::2]) if k not in argv for x in (k, v)]
    if argv[0] == "heat_1d":
        extra += ["--set", "n=16", "--set", "steps=10"]
    code = main(["train", "--prior-fit", "0", *argv, *extra, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("pdeinv train: error: "), err
    assert re.search(match, err), err


def test_steps_in_float_notation_is_accepted():
    assert pdeinv.load_problem("heat_1d", n=8, steps="1e2").settings["steps"] == 100


def test_time_budget_alone_is_not_cut_at_1000_steps():
    from pdeinv.cli import build_parser
    from pdeinv.cli.commands._checks import steps

    args = build_parser().parse_args(["train", "--prior-fit", "0",
                                      "heat_1d", "--out", "x", "--time-budget", "30"])
    assert args.steps is None and steps(args) is None  # the budget alone decides
    assert steps(build_parser().parse_args(["train", "heat_1d", "--out", "x"])) == 1000


def test_export_samples_above_n_test_says_so(tmp_path, capsys):
    argv = [a if a != "0" else "50" for a in SMALL]  # --export-samples 50 with 8 test samples
    assert main(["train", "--prior-fit", "0", "heat_1d", *argv, "--out", str(tmp_path)]) == 0
    assert "warning: --export-samples 50 is more than the 8 test samples" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["wave_sensors_2d", "heat_sensors_2d"])
def test_demo_runs_on_sensor_scenes(name, capsys):
    assert main(["demo", name, "--batch", "2", "--set", "n=8"]) == 0
    assert "dot_product_test" in capsys.readouterr().out


def test_problems_lists_settings_and_defaults(capsys):
    assert main(["problems"]) == 0
    out = capsys.readouterr().out
    assert "heat_2d: Heat on the unit square" in out and "n=32" in out and "kappa=0.01" in out


def test_setup_progress_line(capsys):
    from argparse import Namespace

    from pdeinv.cli.commands import build_problem
    from pdeinv.cli.logs import cli_logging

    with cli_logging(Namespace()):  # the CLI's logging at INFO (pdeinv.cli.logs)
        build_problem("train", "heat_1d", ["n=8"], after_s=0.0)
    err = capsys.readouterr().err
    assert re.search(r"pdeinv train: built heat_1d \(7 unknowns\) in \d", err), err


def test_help_does_not_import_torch():
    code = "import sys, pdeinv.cli; pdeinv.cli.build_parser(); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_optimizer_as_factory_class_or_instance_is_the_same():
    p = [torch.nn.Parameter(torch.zeros(3))]
    specs = [pdeinv.adam(1e-3), torch.optim.Adam, torch.optim.Adam([torch.nn.Parameter(torch.ones(1))])]
    assert len({json.dumps(optimizer_hyperparameters(s), sort_keys=True, default=str) for s in specs}) == 1
    assert all(make_optimizer(s, p).param_groups[0]["params"][0] is p[0] for s in specs)
    heat = pdeinv.load_problem("heat_1d", n=8)
    res = pdeinv.train(heat, pdeinv.GD(optimizer=torch.optim.SGD([p[0]], lr=0.1)), steps=2, n_train=8,
                       n_test=4, batch_size=4, prior=None)
    assert np.isfinite(res.metrics["x_err"])


def test_gd_means_the_same_in_python_and_on_the_command_line():
    cli_rule, _ = make_rule("gd", "heat_2d")
    assert pdeinv.GD().hyperparameters() == cli_rule.hyperparameters()


def test_checkpoint_creates_its_folder_and_fails_early(tmp_path):
    pdeinv.Checkpoint(tmp_path / "a" / "b" / "ckpt.pt")
    assert (tmp_path / "a" / "b").is_dir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file; expected a directory"):
        pdeinv.Checkpoint(tmp_path / "file" / "ckpt.pt")


def test_zero_last_layer():
    net = pdeinv.nets.zero_last_layer(torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Tanh(),
                                                          torch.nn.Linear(4, 2)))
    assert not net[2].weight.any() and not net[2].bias.any() and net[0].weight.any()
    with pytest.raises(ValueError, match="has no torch.nn.Linear"):
        pdeinv.nets.zero_last_layer(torch.nn.Tanh())


def test_wave_1d_default_sees_every_mode():
    """cos(kπcT) ≠ 0 for every k at the default T (T = 0.5 hid every odd mode)."""
    p = pdeinv.load_problem("wave_1d")
    k = np.arange(1, p.N + 1)
    assert np.abs(np.cos(k * np.pi * p.settings["c"] * p.settings["T"])).min() > 0.49


def test_plots_show_sensors_and_ticks():
    import matplotlib

    matplotlib.use("Agg")
    p = pdeinv.load_problem("heat_sensors_2d", n=8, sensors=5)
    x, _ = p.sample(1)
    ax = pdeinv.io.plots.plot_prediction(p, x, x).axes[0]
    assert len(ax.get_xticks()) > 0 and any(line.get_label() == "sensors" for line in ax.lines)


@pytest.mark.slow
def test_gd_defaults_do_not_blow_up_on_the_sensor_scene(tmp_path):
    """``train wave_sensors_2d --method gd`` at its defaults: 2.4e34 by step 19 with lr 0.01; with
    every whitened direction (1024 of 1024 training rows) x-error 2.2 after 25 steps (the trailing
    directions amplified on new data). The default (lr 1 in units of the stable step, one whitened
    direction per 8 rows) takes 25 steps with no rejection, a falling loss and an error below the
    zero network's 1; run.json records the cap and the run reloads with it."""
    out = tmp_path / "o"
    assert main(["train", "--prior-fit", "0",
                 "wave_sensors_2d", "--method", "gd", "--steps", "25", "--eval-every", "25",
                 "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["rejected_steps"] == 0 and m["x_err"] < 0.95, m
    losses = np.loadtxt(out / "history.csv", delimiter=",", skiprows=1, usecols=2)
    assert losses[-1] < 0.95 * losses[0]
    network = json.loads((out / "run.json").read_text())["network"]
    assert network == {"kind": "default", "rows_per_component": 8, "correction": "grid"}
    _, model = pdeinv.load_run(out)
    assert int((model.base.pre.gain > 0).sum()) == 1024 // 8  # the fitted cap travels with model.pt
