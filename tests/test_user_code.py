"""A user's code that fails after loading (a sampler, a network factory, a message that cannot be printed) is
one line with its file and line (exit 2), never a traceback without -v; a sampler's draws are checked before
use; any other unexpected exception is one line naming an internal error (exit 1); a write torch's
serializer fails (a full disk) is 'cannot write'."""

from __future__ import annotations

import numpy as np
import pytest

import pdeinv
from pdeinv.cli import main
from pdeinv.util.files import atomic_write

pytestmark = pytest.mark.usefixtures("one_thread")

SCENE = ("import numpy as np\nfrom pdeinv import load_problem\n\n\n"
         "def make(**overrides):\n    p = load_problem('heat_1d', n=16)\n{body}    return p\n")


def _module(tmp_path, name, body):
    path = tmp_path / f"{name}.py"
    path.write_text(SCENE.format(body=body))
    return path


def test_a_sampler_that_raises_while_training_is_one_line_with_its_file_and_line(tmp_path, capsys):
    body = "    def bad(n, rng):\n        raise RuntimeError('sampler broke')\n    p.sampler = bad\n"
    module = _module(tmp_path, "raising", body)
    out = str(tmp_path / "r")
    code = main(["train", str(module), "--steps", "1", "--prior-fit", "0", "-q", "--out", out])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and err.count("\n") == 1, err
    assert err.startswith(f"pdeinv train: error: {module}, line 8, in bad: RuntimeError: sampler broke"), err


def test_explain_refuses_a_sampler_the_run_would_refuse(tmp_path, capsys):
    """``--explain`` prints the plan, then takes the run's first draws: a sampler that raises is refused
    there, in the run's one line and exit code, not only once the run has started."""
    body = "    def bad(n, rng):\n        raise RuntimeError('sampler broke')\n    p.sampler = bad\n"
    module = _module(tmp_path, "raising", body)
    code = main(["train", str(module), "--prior-fit", "0", "--explain"])
    out, err = capsys.readouterr()
    assert code == 2 and "rule" in out and "Traceback" not in err and err.count("\n") == 1, err
    assert "line 8, in bad: RuntimeError: sampler broke" in err
    assert main(["train", str(_module(tmp_path, "fine", "")), "--prior-fit", "0", "--explain"]) == 0


@pytest.mark.parametrize(("body", "says"), [
    ("    p.sampler = lambda n, rng: np.full((n, p.N), np.nan)\n",
     "its sampler returned 240 NaN/Inf values"),
    ("    p.sampler = lambda n, rng: np.ones((n, p.N + 1))\n",
     "its sampler returned shape (16, 16) for 16 draws; expected (16, 15)"),
    ("    p.sampler = lambda n, rng: 1e300 * np.ones((n, p.N))\n",
     "its sampler returned values up to 1e+300"),
])
def test_a_samplers_draws_are_checked_before_use(tmp_path, body, says):
    p = pdeinv.load_problem(_module(tmp_path, "odd", body))
    with pytest.raises(ValueError, match="problem 'heat_1d': ") as info:
        p.sample(16)
    assert says in str(info.value)


def test_a_mesh_and_an_operator_of_other_sizes_are_refused():
    p = pdeinv.load_problem("heat_1d", n=16)
    with pytest.raises(ValueError, match="its mesh has 15 unknowns but its operator takes 7"):
        pdeinv.Problem("x", p.disc, pdeinv.physics.Matrix(np.eye(7)), p.sampler)


def test_an_exception_whose_message_cannot_be_printed_still_gives_one_line(tmp_path, capsys):
    module = tmp_path / "unprintable.py"
    module.write_text("class E(Exception):\n    def __str__(self):\n        raise RuntimeError('no')\n\n\n"
                      "def make(**overrides):\n    raise E()\n")
    assert main(["train", str(module), "--steps", "1", "-q", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "line 7, in make: E: (its message cannot be printed: RuntimeError)" in err
    assert "Traceback" not in err


def test_an_internal_error_is_one_line_and_exit_1(monkeypatch, capsys):
    """An exception from no user's frame (here a builtin's KeyError) is pdeinv's own: one line, exit 1."""
    from pdeinv.cli import build_parser

    parser = build_parser()
    monkeypatch.setattr("pdeinv.cli.build_parser", lambda: parser)
    parser.commands["problems"].set_defaults(func={}.pop)  # a builtin: no Python frame of its own
    assert main(["problems"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("pdeinv problems: internal error: KeyError: ") and err.count("\n") == 1, err
    assert err.endswith("(-v shows the traceback; please report it)\n")


def test_a_write_torchs_serializer_fails_is_cannot_write(tmp_path):
    def full(fh):
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 123 vs 456")

    with pytest.raises(OSError, match="the writer failed"):
        atomic_write(tmp_path / "model.pt", full)
    assert list(tmp_path.iterdir()) == []  # no temporary left behind
