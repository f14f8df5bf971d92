"""Disk cache of factorizations (pdeinv.util.cache): hits, misses, corrupt entries, concurrency, switches."""

import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import pdeinv
from pdeinv.fem.forms import discretize
from pdeinv.physics import Heat, Modal
from pdeinv.physics.backends import modes
from pdeinv.util import cache


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """A fresh, empty cache folder for one test, cache on."""
    monkeypatch.setenv("PDEINV_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setenv("PDEINV_NO_CACHE", "0")
    return tmp_path / "c"


class Build:
    """A build that counts its calls."""

    def __init__(self, scale=1.0):
        self.calls, self.scale = 0, scale

    def __call__(self):
        self.calls += 1
        return {"lam": self.scale * np.arange(3.0), "Phi": self.scale * np.ones((5, 3))}


def parts(scale=1.0, tol=1e-14):
    A = sp.diags([2.0, 3.0, 4.0, 5.0, 6.0]).tocsr()
    return {"A": scale * A, "b": np.arange(4.0), "settings": {"tol": tol, "steps": 100, "name": "be"}}


def entries(folder):
    return sorted(folder.glob("t-*.npz"))


def test_hit_does_not_build_and_returns_equal_arrays(folder):
    build = Build()
    first = cache.cached("t", parts(), build)
    second = cache.cached("t", parts(), build)
    assert build.calls == 1 and len(entries(folder)) == 1
    for name in first:
        assert np.array_equal(first[name], second[name]) and first[name].dtype == second[name].dtype


@pytest.mark.parametrize("changed", [parts(tol=1e-13), parts(scale=1.0 + 1e-15),
                                     {**parts(), "b": np.arange(5.0)}], ids=["settings", "matrix", "array"])
def test_a_change_of_settings_or_matrices_misses(folder, changed):
    build = Build()
    cache.cached("t", parts(), build)
    cache.cached("t", changed, build)
    assert build.calls == 2 and len(entries(folder)) == 2


def test_key_is_a_content_hash():
    """The same matrix in another storage (unsorted CSR, COO, int64 indices) has the same key."""
    A = sp.csr_matrix((np.array([1.0, 2.0, 3.0]), np.array([2, 0, 1]), np.array([0, 2, 3])), shape=(2, 3))
    B = A.copy()
    B.sort_indices()
    B.indices, B.indptr = B.indices.astype(np.int64), B.indptr.astype(np.int64)
    assert len({cache.key("t", {"A": X}) for X in (A, B, A.tocoo(), A.tocsc())}) == 1
    assert cache.key("t", {"A": A}) != cache.key("t", {"A": A.T})
    numpy_scalars = {"s": {"n": np.int64(3), "x": np.float32(0.5)}}
    assert cache.key("t", numpy_scalars) == cache.key("t", {"s": {"x": 0.5, "n": 3}})
    assert cache.key("t", parts()) != cache.key("u", parts())
    with pytest.raises(TypeError, match="'f' is a function"):
        cache.key("t", {"f": lambda: 0})
    with pytest.raises(ValueError, match="kind 'a/b'"):
        cache.cached("a/b", parts(), Build())


@pytest.mark.parametrize("damage", ["garbage", "truncate", "other key", "empty"])
def test_a_corrupt_entry_is_rebuilt_and_replaced(folder, damage):
    build = Build()
    cache.cached("t", parts(), build)
    (path,) = entries(folder)
    if damage == "garbage":
        path.write_bytes(b"not a zip file at all" * 10)
    elif damage == "truncate":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "other key":  # a valid entry, stored under the wrong name
        cache.cached("t", parts(tol=0.5), Build(scale=2.0))
        other = next(p for p in entries(folder) if p != path)
        path.write_bytes(other.read_bytes())
    else:
        path.write_bytes(b"")
    with pytest.warns(RuntimeWarning, match="is invalid"):
        got = cache.cached("t", parts(), build)
    assert build.calls == 2 and np.array_equal(got["Phi"], np.ones((5, 3)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.array_equal(cache.cached("t", parts(), build)["lam"], np.arange(3.0))
    assert build.calls == 2  # the replacement is a valid entry


def test_a_changed_array_in_an_entry_fails_its_content_hash(folder):
    cache.cached("t", parts(), Build())
    (path,) = entries(folder)
    with np.load(path) as z:
        arrays = {n: z[n] for n in z.files}
    arrays["lam"][0] = 7.0
    np.savez(path, **arrays)
    with pytest.warns(RuntimeWarning, match="content hash"):
        assert cache.cached("t", parts(), Build())["lam"][0] == 0.0


def test_verify_rejects_an_entry(folder):
    cache.cached("t", parts(), Build())
    build = Build()
    with pytest.warns(RuntimeWarning, match="too few"):
        cache.cached("t", parts(), build, verify=lambda a: "too few" if len(a["lam"]) < 4 else None)
    assert build.calls == 1


WRITER = textwrap.dedent("""
    import os, sys, time
    from pathlib import Path
    import numpy as np
    from pdeinv.util import cache

    flags = Path(sys.argv[1])
    def build():  # both processes are inside build (both missed) before either writes
        (flags / sys.argv[2]).touch()
        t = time.time()
        while len(list(flags.glob("p*"))) < 2 and time.time() - t < 120:
            time.sleep(0.01)
        return {"x": np.arange(100000.0) * float(sys.argv[3])}
    got = cache.cached("t", {"s": 1}, build)
    assert got["x"][1] == float(sys.argv[3])
""")


def test_two_processes_building_the_same_key_both_succeed(folder, tmp_path):
    flags = tmp_path / "flags"
    flags.mkdir()
    procs = [subprocess.Popen([sys.executable, "-c", WRITER, str(flags), f"p{i}", str(i + 1)],
                              stderr=subprocess.PIPE, text=True) for i in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    build = Build()
    got = cache.cached("t", {"s": 1}, build)
    assert build.calls == 0 and got["x"][1] in (1.0, 2.0)  # one of the two complete entries
    assert [p.name for p in folder.iterdir()] == [entries(folder)[0].name]  # no temporaries left


@pytest.mark.parametrize("where", ["file", "below a file"])
def test_an_unwritable_folder_warns_once_and_goes_on_uncached(tmp_path, monkeypatch, where):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("x")
    target = blocker if where == "file" else blocker / "sub"
    monkeypatch.setenv("PDEINV_CACHE_DIR", str(target))
    monkeypatch.setenv("PDEINV_NO_CACHE", "0")
    build = Build()
    with pytest.warns(RuntimeWarning, match="cannot be written.*going on uncached"):
        got = cache.cached("t", parts(), build)
    assert np.array_equal(got["lam"], np.arange(3.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # one warning per folder
        cache.cached("t", parts(), build)
    assert build.calls == 2 and blocker.read_text() == "x"


@pytest.mark.parametrize("how", ["env", "argument"])
def test_the_cache_can_be_switched_off(folder, monkeypatch, how):
    if how == "env":
        monkeypatch.setenv("PDEINV_NO_CACHE", "1")
    build = Build()
    for _ in range(2):
        cache.cached("t", parts(), build, cache=(how == "env"))
    assert build.calls == 2 and not folder.exists()


def test_default_folder_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.delenv("PDEINV_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache.folder() == tmp_path / "pdeinv"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert cache.folder() == Path.home() / ".cache" / "pdeinv"


class _Called(Exception):
    pass


@pytest.mark.parametrize("command", ["train", "bench", "stress"])
def test_no_cache_flag_switches_the_cache_off(folder, monkeypatch, tmp_path, command):
    import importlib

    from pdeinv import cli
    from pdeinv.cli import commands

    args = cli.build_parser().parse_args([command, "heat_1d", "--out", str(tmp_path / "o"), "--no-cache"])
    commands.no_cache(args)
    assert os.environ["PDEINV_NO_CACHE"] == "1" and not cache.enabled()
    monkeypatch.setenv("PDEINV_NO_CACHE", "0")
    module = importlib.import_module(f"pdeinv.cli.commands.{command}")

    def called(a):
        raise _Called(a.no_cache)

    monkeypatch.setattr(module, "no_cache", called)  # the command applies the flag before any work
    with pytest.raises(_Called, match="True"):
        args.func(args)


def _heat(n=10, **kw):
    d = discretize(pdeinv.fem.mesh.unit_square(n))
    return Heat(d.M, d.K, backend="steps", measure=d.measure, dim=d.dim, **kw)


@pytest.mark.parametrize("path", ["dense", "eigsh"])
def test_modal_backend_from_the_cache_equals_the_fresh_one_bitwise(folder, monkeypatch, path):
    if path == "eigsh":
        monkeypatch.setattr(modes, "DENSE_MAX", 10)
    heat = _heat(kappa=0.05)
    fresh = Modal(heat, cache=False)
    assert not folder.exists()
    stored = Modal(heat)
    assert len(list(folder.glob("modal-*.npz"))) == 1

    def no_build(*a, **k):
        raise AssertionError("built although cached")

    monkeypatch.setattr("pdeinv.physics.backends.modal.lowest_modes", no_build)
    hit = Modal(heat)
    for name in ("lam", "Phi", "g", "MPhi"):
        assert np.array_equal(getattr(hit, name), getattr(fresh, name))
        assert np.array_equal(getattr(stored, name), getattr(fresh, name))
    with pytest.raises(AssertionError, match="built although"):  # another tolerance: another entry
        Modal(_heat(kappa=0.05, tol=1e-12))


def test_the_folder_is_kept_under_its_size_limit_least_recently_used_first(folder, monkeypatch):
    import os
    import time

    big = lambda: {"a": np.zeros(20_000)}  # noqa: E731  160 kB each
    for i in range(3):
        cache.cached("t", parts(tol=10.0 ** -(10 + i)), big)
    paths = {i: folder / f"t-{cache.key('t', parts(tol=10.0 ** -(10 + i)))}.npz" for i in range(3)}
    now = time.time()
    for i, age in ((0, 30), (1, 20), (2, 10)):
        os.utime(paths[i], (now - age, now - age))
    cache.cached("t", parts(tol=1e-10), big)  # a hit makes entry 0 the most recently used
    monkeypatch.setenv("PDEINV_CACHE_MAX_GB", str(3.5 * 160_400 / 1e9))
    cache.cached("t", parts(tol=1e-20), big)  # a fourth entry: the oldest (entry 1) goes
    left = set(entries(folder))
    assert paths[1] not in left and {paths[0], paths[2]} <= left and len(left) == 3
    mine = folder / "modal-mine.npz"  # a user's file in the folder, named like an entry: never evicted
    np.savez(mine, a=np.zeros(50_000))
    monkeypatch.setenv("PDEINV_CACHE_MAX_GB", "1e-9")  # smaller than any entry: only the new one stays
    cache.cached("t", parts(tol=1e-21), big)
    assert len([p for p in entries(folder) if p != mine]) == 1 and mine.is_file()
    monkeypatch.setenv("PDEINV_CACHE_MAX_GB", "-1")
    with pytest.raises(ValueError, match="PDEINV_CACHE_MAX_GB='-1' is not allowed"):
        cache.cached("t", parts(tol=1e-22), big)
