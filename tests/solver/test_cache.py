"""The compile cache verifies what it loads (issue #12 item 4): a tampered entry is never
imported as it is; it is discarded, compiled again, and the run still gives its result.

Cost (issue 17 item 7): each CLI process here imports spidersim (about 2.5 s of CPU), so
entries are written once per module by real runs and copied (``pristine``,
``pristine_jit``), and a run whose only question is "is the entry sound now" runs in this
process (:func:`_run_here`, the per-process module table cleared, so the entry is read from
the folder and verified as a fresh process would). Every tampering and corruption is still
met by a fresh process, as a user's next run would meet it."""
import contextlib
import glob
import io
import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SERVO = os.path.join(ROOT, "diagrams", "three_lags.yaml")
OTHER = os.path.join(ROOT, "diagrams", "algebraic_loop.yaml")


def _run(cache, path=SERVO, out=None):
    env = dict(os.environ, SPIDERSIM_CACHE=str(cache))
    return subprocess.run([sys.executable, "-m", "spidersim.cli", "run", path, "--no-jit",
                           "--no-plots", "--out", str(out or str(cache) + "_out")],
                          capture_output=True, text=True, env=env, timeout=300)


def _run_here(cache, monkeypatch, path=SERVO, out=None):
    """:func:`_run` in this process: ``spidersim.cli.main`` with the same arguments and
    ``SPIDERSIM_CACHE``, spidersim's per-process module table emptied first (else a
    module this process already imported would be used without reading the folder);
    returns ``(exit status, stderr)``."""
    from spidersim.cli import main
    from spidersim.solver import compiled
    monkeypatch.setenv("SPIDERSIM_CACHE", str(cache))
    monkeypatch.setattr(compiled, "_LOADED", {})
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main(["run", str(path), "--no-jit", "--no-plots", "--out",
                   str(out or str(cache) + "_out")])
    return rc, err.getvalue()


def _entry(cache):
    (py,) = [p for p in glob.glob(os.path.join(cache, "spidersim_gen_*.py"))]
    return py


def _truncate(py, marker, other):
    text = open(py).read()
    open(py, "w").write(text[: len(text) // 2])


def _empty(py, marker, other):
    open(py, "w").close()


def _append(py, marker, other):
    with open(py, "a") as fh:
        fh.write(f"\nimport pathlib\npathlib.Path({str(marker)!r}).write_text('ran')\n")


def _swap(py, marker, other):
    """Another diagram's module, with a hash file that matches the swapped text."""
    import hashlib
    text = open(other).read()
    open(py, "w").write(text)
    open(py[:-3] + ".sha256", "w").write(hashlib.sha256(text.encode()).hexdigest() + "\n")


def _no_hash(py, marker, other):
    os.remove(py[:-3] + ".sha256")


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """Two cache folders made once per module by real runs (the CLI in a fresh process):
    one holding the entry of ``three_lags.yaml``, one that of ``algebraic_loop.yaml``.
    Tests copy the first (``_copy``) instead of each writing the same entry again; the
    second is only read (the ``swap`` tampering)."""
    base = tmp_path_factory.mktemp("pristine")
    cache, other = base / "cache", base / "other"
    first = _run(cache)
    assert first.returncode == 0, first.stderr
    assert _run(other, OTHER).returncode == 0
    return cache, other


def _copy(pristine, dest):
    shutil.copytree(pristine[0], dest)
    return dest


@pytest.mark.parametrize("tamper", [_truncate, _empty, _append, _swap, _no_hash],
                         ids=lambda f: f.__name__.strip("_"))
def test_tampered_entry_is_discarded_and_recompiled(tmp_path, tamper, pristine, monkeypatch):
    """A fresh process meets the tampered entry: warns, discards it and writes it anew (no
    traceback, the appended code never ran); the next run (here, in this process, reading
    the folder) loads the rewritten entry without a word."""
    cache, other_cache = _copy(pristine, tmp_path / "cache"), pristine[1]
    marker = tmp_path / "marker"
    py = _entry(cache)
    tamper(py, marker, _entry(other_cache))
    second = _run(cache)
    assert second.returncode == 0, second.stderr
    assert "does not match its hash" in second.stderr and "Traceback" not in second.stderr
    assert not marker.exists()
    assert "pathlib" not in open(py).read()
    # the entry is sound again: a third run loads it without a warning
    rc, err = _run_here(cache, monkeypatch)
    assert rc == 0 and "cache:" not in err, err


def test_untouched_entry_is_loaded_without_a_word(tmp_path, pristine):
    cache = _copy(pristine, tmp_path / "cache")
    again = _run(cache)
    assert again.returncode == 0 and "cache:" not in again.stderr


@pytest.mark.parametrize("kind", ["file", "unwritable_parent"])
def test_unusable_cache_falls_back_to_a_temporary_folder(tmp_path, kind):
    if kind == "file":
        cache = tmp_path / "a_file"
        cache.write_text("")
    else:
        blocker = tmp_path / "blocker"
        blocker.write_text("")
        cache = blocker / "cache"
    res = _run(cache, out=tmp_path / "out")
    assert res.returncode == 0, res.stderr
    assert "not a writable folder" in res.stderr and "Traceback" not in res.stderr


def test_cache_info_and_clear(tmp_path, pristine):
    cache = _copy(pristine, tmp_path / "cache")
    keep = cache / "mine.txt"
    keep.write_text("not spidersim's")
    # TMPDIR: the user's fallback folder (cleared too) is the test's own
    env = dict(os.environ, SPIDERSIM_CACHE=str(cache), TMPDIR=str(tmp_path))
    info = subprocess.run([sys.executable, "-m", "spidersim.cli", "cache", "info"],
                          capture_output=True, text=True, env=env)
    assert info.returncode == 0 and "entries: 1 " in info.stdout
    clear = subprocess.run([sys.executable, "-m", "spidersim.cli", "cache", "clear"],
                           capture_output=True, text=True, env=env)
    assert clear.returncode == 0
    assert not glob.glob(os.path.join(cache, "spidersim_gen_*"))
    assert keep.exists()                      # only spidersim's own files are removed


# ---------------------------------------------------------------- numba's own cache files
TINY = """\
blocks:
  c: {type: Constant, value: 1}
  g: {type: Gain, k: 2}
connections:
  - c.y -> g.u
simulation: {t_end: 0.01}
"""


def _run_jit(cache, path, out):
    env = dict(os.environ, SPIDERSIM_CACHE=str(cache))
    return subprocess.run([sys.executable, "-m", "spidersim.cli", "run", str(path),
                           "--no-plots", "--out", str(out)],
                          capture_output=True, text=True, env=env, timeout=600)


def _truncate_nbc(folder):
    for f in glob.glob(os.path.join(folder, "__pycache__", "spidersim_gen_*.nbc")):
        data = open(f, "rb").read()
        open(f, "wb").write(data[:50])


def _garbage_nbi(folder):
    for f in glob.glob(os.path.join(folder, "__pycache__", "spidersim_gen_*.nbi")):
        open(f, "w").write("garbage\n")


@pytest.fixture(scope="module")
def pristine_jit(tmp_path_factory):
    """One compiled run of ``TINY`` (the CLI in a fresh process, numba's files written beside
    the entry), made once per module; the tests copy its cache folder (file times kept, so
    numba's index still matches) instead of each compiling the same entry again."""
    base = tmp_path_factory.mktemp("pristine_jit")
    cache, path = base / "cache", base / "tiny.yaml"
    path.write_text(TINY)
    first = _run_jit(cache, path, base / "o1")
    assert first.returncode == 0, first.stderr
    assert glob.glob(os.path.join(cache, "__pycache__", "spidersim_gen_*.nbc"))
    return cache, path, base / "o1"


@pytest.mark.parametrize("corrupt", [_truncate_nbc, _garbage_nbi],
                         ids=lambda f: f.__name__.strip("_"))
def test_corrupt_numba_cache_is_cleared_and_compiled_again(tmp_path, corrupt, pristine_jit):
    """The module is sound but numba's machine-code files beside it are not: a one-line
    warning, numba compiles again, the result is the same; the next run is quiet."""
    cache = tmp_path / "cache"
    shutil.copytree(pristine_jit[0], cache)
    path, o1 = pristine_jit[1], pristine_jit[2]
    corrupt(cache)
    second = _run_jit(cache, path, tmp_path / "o2")
    assert second.returncode == 0, second.stderr
    assert "Traceback" not in second.stderr
    warnings = [ln for ln in second.stderr.splitlines() if "cache:" in ln]
    assert len(warnings) == 1 and "compiling again" in warnings[0], second.stderr
    import numpy as np
    a, b = np.load(o1 / "result.npz"), np.load(tmp_path / "o2" / "result.npz")
    assert np.array_equal(a["g.y"], b["g.y"]) and a["g.y"][0] == 2.0
    third = _run_jit(cache, path, tmp_path / "o3")
    assert third.returncode == 0 and "cache:" not in third.stderr


@pytest.fixture
def own_cache(tmp_path, monkeypatch):
    """A private cache folder and a clean per-process module table."""
    from spidersim.solver import compiled
    monkeypatch.setenv("SPIDERSIM_CACHE", str(tmp_path / "cache"))
    saved = dict(compiled._LOADED)
    compiled._LOADED.clear()
    yield compiled, tmp_path / "cache"
    compiled._LOADED.clear()
    compiled._LOADED.update(saved)


def _fake_numba_file(compiled, folder, text):
    key = compiled._sha(compiled.package_hash() + text)[:20]
    pyc = folder / "__pycache__"
    pyc.mkdir(parents=True, exist_ok=True)
    f = pyc / f"{compiled.PREFIX}{key}.rhs-1.py311.nbi"
    f.write_text("stale")
    return f


def test_check_failing_twice_asks_for_cache_clear(own_cache, capsys, monkeypatch):
    """A check that fails again after numba's files were cleared (here: the files cannot
    be removed) is a clear error that says what to do, not a traceback."""
    from spidersim.errors import SpidersimError
    compiled, folder = own_cache
    text = "X = 1\n"
    folder.mkdir()
    nbi = _fake_numba_file(compiled, folder, text)
    monkeypatch.setattr(compiled, "_remove", lambda f: None)      # removal fails

    def check(mod):
        raise ValueError("corrupt index")
    with pytest.raises(SpidersimError, match="spidersim cache clear"):
        compiled.load_module(text, jit=True, check=check)
    assert nbi.exists()
    assert "could not be loaded" in capsys.readouterr().err


def test_check_failing_once_is_retried(own_cache, capsys):
    compiled, folder = own_cache
    text = "X = 2\n"
    folder.mkdir()
    nbi = _fake_numba_file(compiled, folder, text)
    calls = []

    def check(mod):
        calls.append(mod)
        if len(calls) == 1:
            raise EOFError("truncated")
    mod, _key, _s = compiled.load_module(text, jit=True, check=check)
    assert mod.X == 2 and len(calls) == 2 and calls[0] is not calls[1]   # imported anew
    assert not nbi.exists()
    err = capsys.readouterr().err
    assert err.count("spidersim: cache:") == 1


def test_error_without_numba_files_is_not_blamed_on_the_cache(own_cache, capsys):
    """No numba file to blame: the error is raised as it is (a bug to report), and the
    user's own errors (SpidersimError) always are."""
    from spidersim.errors import SpidersimError
    compiled, _folder = own_cache

    def bug(mod):
        raise ZeroDivisionError("a bug")
    with pytest.raises(ZeroDivisionError):
        compiled.load_module("X = 3\n", jit=True, check=bug)

    def user(mod):
        raise SpidersimError("user error")
    with pytest.raises(SpidersimError, match="user error"):
        compiled.load_module("X = 4\n", jit=True, check=user)
    assert "cache:" not in capsys.readouterr().err


def test_cache_info_lists_folder_entries_and_size(tmp_path, pristine):
    """``cache info`` (a fresh process) on an empty folder, then on one holding the two
    entries the real runs of ``pristine`` wrote (copied: the same files two runs of the two
    diagrams into this folder would write): their number and size."""
    cache = tmp_path / "cache"
    env = dict(os.environ, SPIDERSIM_CACHE=str(cache))
    cmd = [sys.executable, "-m", "spidersim.cli", "cache", "info"]
    empty = subprocess.run(cmd, capture_output=True, text=True, env=env)
    assert empty.returncode == 0 and "entries: 0 " in empty.stdout and str(cache) in empty.stdout
    for src in pristine:
        shutil.copytree(src, cache, dirs_exist_ok=True)
    full = subprocess.run(cmd, capture_output=True, text=True, env=env)
    assert "entries: 2 " in full.stdout
    size = sum(os.path.getsize(p) for p in glob.glob(os.path.join(cache, "spidersim_gen_*")))
    assert f"{size / 1e6:.1f} MB" in full.stdout


def test_kernel_caches_are_dropped_when_a_source_changes(tmp_path):
    """numba keys a cached kernel by its own file only, so an edit of a function it calls
    (multibody/kernels.py under the Arm's kernels) would load stale machine code: a stamp
    of spidersim's source hash beside the caches drops every .nbi/.nbc when it differs,
    and leaves them when it matches."""
    from spidersim.solver.compiled import package_hash, refresh_kernel_caches
    root = tmp_path / "pkg"
    cache = root / "blocks" / "__pycache__"
    cache.mkdir(parents=True)
    (root / "__pycache__").mkdir()
    stamp = root / "__pycache__" / "numba-kernels.stamp"
    kept = cache / "arm.Arm.output-1.py311.pyc"
    kept.write_text("not numba's")

    def fill():
        for f in ("arm.Arm.output-1.py311.nbi", "arm.Arm.output-1.py311.1.nbc"):
            (cache / f).write_text("machine code")

    fill()
    stamp.write_text("an older source hash")
    assert refresh_kernel_caches(str(root)) is True
    assert not list(cache.glob("*.nb*")) and kept.exists()
    assert stamp.read_text() == package_hash()
    fill()                                   # same sources: nothing is dropped
    assert refresh_kernel_caches(str(root)) is False
    assert len(list(cache.glob("*.nb*"))) == 2


def test_clear_removes_only_cache_entries(tmp_path, monkeypatch):
    """``cache clear`` removes the files of cache entries (module, hash, numba's files) and
    leaves a file that merely starts with the same prefix (it deleted
    ``spidersim_gen_notmine.txt``)."""
    from spidersim.solver import compiled
    monkeypatch.setenv("SPIDERSIM_CACHE", str(tmp_path))
    monkeypatch.setattr(compiled, "fallback_path", lambda: str(tmp_path / "no_fallback"))
    key = "0123456789abcdef0123"
    (tmp_path / "__pycache__").mkdir()
    ours = [tmp_path / f"spidersim_gen_{key}.py", tmp_path / f"spidersim_gen_{key}.sha256",
            tmp_path / "__pycache__" / f"spidersim_gen_{key}.outputs-45.py311.nbi",
            tmp_path / "__pycache__" / f"spidersim_gen_{key}.outputs-45.py311.1.nbc"]
    theirs = [tmp_path / "spidersim_gen_notmine.txt", tmp_path / f"spidersim_gen_{key}.py.bak",
              tmp_path / "notes.txt"]
    for f in ours + theirs:
        f.write_text("x")
    assert compiled.clear() == len(ours)
    assert not any(f.exists() for f in ours) and all(f.exists() for f in theirs)


def test_cache_info_counts_only_its_own_entries_at_its_own_depth(tmp_path, monkeypatch):
    """``cache info`` counts the files of cache entries in the folder and its
    ``__pycache__`` only: with ``SPIDERSIM_CACHE=/`` it walked the whole file system and
    counted any ``spidersim_gen_*`` anywhere (a file of the same prefix that is no entry,
    one in a deeper folder, a link to a big file are not its own)."""
    from spidersim.solver import compiled
    monkeypatch.setenv("SPIDERSIM_CACHE", str(tmp_path))
    monkeypatch.setattr(compiled, "fallback_path", lambda: str(tmp_path / "no_fallback"))
    key = "0123456789abcdef0123"
    (tmp_path / "__pycache__").mkdir()
    (tmp_path / "deeper").mkdir()
    ours = {tmp_path / f"spidersim_gen_{key}.py": 100, tmp_path / f"spidersim_gen_{key}.sha256": 64,
            tmp_path / "__pycache__" / f"spidersim_gen_{key}.outputs-45.py311.nbi": 10,
            tmp_path / "__pycache__" / f"spidersim_gen_{key}.outputs-45.py311.1.nbc": 1000}
    theirs = {tmp_path / "spidersim_gen_notmine.py": 5000,
              tmp_path / "deeper" / f"spidersim_gen_{key[::-1]}.py": 7000,
              tmp_path / "big.bin": 9000}
    for f, n in {**ours, **theirs}.items():
        f.write_bytes(b"x" * n)
    os.symlink(tmp_path / "big.bin", tmp_path / f"spidersim_gen_{'f' * 20}.py")
    info = compiled.info()
    assert (info["entries"], info["bytes"]) == (1, sum(ours.values()))
