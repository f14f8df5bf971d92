"""`pdeinv problems` past a user's module that never finishes importing or ends the process (a fuzz round:
`while True: pass` at import hung the listing, `os._exit(7)` ended it with exit 7 and nothing said). Each
user module is imported in a process of its own (pdeinv.cli.commands.problems); the built-ins are not."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pdeinv.cli import main
from pdeinv.cli.signals import INTERRUPTED, TERMINATED

ROOT = Path(__file__).resolve().parents[1]
GOOD = ('"""A scene of my own."""\nprint("hello from the import")\n'
        'SETTINGS = {"n": (16, int), "kappa": (0.05, float)}\ndef make(**overrides):\n    pass\n')


def _listing(tmp_path, monkeypatch, capsys, **modules) -> str:
    for name, text in modules.items():
        (tmp_path / f"{name}.py").write_text(text)
    monkeypatch.setenv("PDEINV_PROBLEMS", str(tmp_path))
    assert main(["problems"]) == 0
    out = capsys.readouterr().out
    assert "wave_sensors_2d: Photoacoustic" in out and "heat_1d: Heat on (0, 1)" in out  # it went on
    return out


def test_a_module_looping_at_import_is_one_line_and_the_listing_goes_on(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("pdeinv.cli.commands.problems.IMPORT_S", 2)
    start = time.monotonic()
    out = _listing(tmp_path, monkeypatch, capsys, aaa_loops="while True:\n    pass\n")
    assert (f"aaa_loops: did not finish importing in 2 s (a loop at import?)\n"
            f"    from {tmp_path / 'aaa_loops.py'}\n") in out
    assert time.monotonic() - start < 60


def test_a_module_ending_the_process_at_import_is_one_line(tmp_path, monkeypatch, capsys):
    out = _listing(tmp_path, monkeypatch, capsys, exits="import os\nos._exit(7)\n",
                   segfaults="import os, signal\nos.kill(os.getpid(), signal.SIGSEGV)\n")
    assert f"exits: its import ended the process (exit code 7)\n    from {tmp_path / 'exits.py'}\n" in out
    assert (f"segfaults: its import ended the process (signal SIGSEGV)\n"
            f"    from {tmp_path / 'segfaults.py'}\n") in out


def test_a_good_user_module_is_listed_as_before(tmp_path, monkeypatch, capsys):
    out = _listing(tmp_path, monkeypatch, capsys, mine=GOOD)
    lines = out.splitlines()
    at = lines.index("mine: A scene of my own.")  # its print at import stays out of the listing
    assert lines[at:at + 3] == ["mine: A scene of my own.", "    settings: n=16, kappa=0.05",
                                f"    from {tmp_path / 'mine.py'}"]
    assert "hello from the import" not in out


def test_the_child_does_not_import_what_the_module_does_not(tmp_path, monkeypatch, capsys):
    probe = ("import sys\n"
             "__doc__ = f\"loaded torch={'torch' in sys.modules} numpy={'numpy' in sys.modules}\"\n"
             "def make(**overrides):\n    pass\n")
    out = _listing(tmp_path, monkeypatch, capsys, probe=probe)
    assert "probe: loaded torch=False numpy=False\n    settings: see its make()\n" in out


def _looping(tmp_path) -> tuple[subprocess.Popen, Path]:
    """`pdeinv problems` running, its user module `hang` looping at import (its pid in `marker`)."""
    marker = tmp_path / "pid"
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "hang.py").write_text(
        f"import os, pathlib\npathlib.Path({str(marker)!r}).write_text(str(os.getpid()))\n"
        "while True:\n    pass\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PDEINV_PROBLEMS": str(tmp_path / "mods")}
    proc = subprocess.Popen([sys.executable, "-m", "pdeinv", "problems"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not (marker.exists() and marker.read_text()):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1].decode()
        time.sleep(0.05)
    return proc, marker


def _gone(pid: int, wait_s: float = 10) -> bool:
    """Whether process ``pid`` ended (a zombie no one reaped yet counts) within ``wait_s`` seconds."""
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
        except (FileNotFoundError, ProcessLookupError):
            return True
        if state in ("Z", "X"):
            return True
        time.sleep(0.05)
    return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig, code, line", [(signal.SIGINT, INTERRUPTED, "interrupted"),
                                             (signal.SIGTERM, TERMINATED, "terminated (SIGTERM)")])
def test_ctrl_c_during_a_looping_import_stops_the_listing_and_its_child(tmp_path, sig, code, line):
    proc, marker = _looping(tmp_path)
    time.sleep(1)
    proc.send_signal(sig)
    start = time.monotonic()
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError(f"{sig.name} did not stop a listing whose user module loops") from None
    assert time.monotonic() - start < 10
    assert proc.returncode == code and err.decode() == f"pdeinv problems: {line}\n", err.decode()
    assert _gone(int(marker.read_text()), 0.5), "the child importing the module outlived the listing"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_child_ends_when_the_listing_is_killed(tmp_path):
    proc, marker = _looping(tmp_path)
    proc.kill()  # SIGKILL: no handler runs; the child sees its pipe to the parent close
    proc.communicate()
    assert _gone(int(marker.read_text())), "the child importing the module outlived a killed listing"
