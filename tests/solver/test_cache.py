"""The compile cache verifies what it loads (issue #12 item 4): a tampered entry is never
imported as it is; it is discarded, compiled again, and the run still gives its result."""
import glob
import os
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


@pytest.mark.parametrize("tamper", [_truncate, _empty, _append, _swap, _no_hash],
                         ids=lambda f: f.__name__.strip("_"))
def test_tampered_entry_is_discarded_and_recompiled(tmp_path, tamper):
    cache, other_cache = tmp_path / "cache", tmp_path / "other"
    first = _run(cache)
    assert first.returncode == 0, first.stderr
    assert _run(other_cache, OTHER).returncode == 0
    marker = tmp_path / "marker"
    py = _entry(cache)
    tamper(py, marker, _entry(other_cache))
    second = _run(cache)
    assert second.returncode == 0, second.stderr
    assert "does not match its hash" in second.stderr and "Traceback" not in second.stderr
    assert not marker.exists()
    assert "pathlib" not in open(py).read()
    # the entry is sound again: a third run loads it without a warning
    third = _run(cache)
    assert third.returncode == 0 and "cache:" not in third.stderr


def test_untouched_entry_is_loaded_without_a_word(tmp_path):
    cache = tmp_path / "cache"
    assert _run(cache).returncode == 0
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


def test_cache_info_and_clear(tmp_path):
    cache = tmp_path / "cache"
    assert _run(cache).returncode == 0
    keep = cache / "mine.txt"
    keep.write_text("not spidersim's")
    env = dict(os.environ, SPIDERSIM_CACHE=str(cache))
    info = subprocess.run([sys.executable, "-m", "spidersim.cli", "cache", "info"],
                          capture_output=True, text=True, env=env)
    assert info.returncode == 0 and "entries: 1 " in info.stdout
    clear = subprocess.run([sys.executable, "-m", "spidersim.cli", "cache", "clear"],
                           capture_output=True, text=True, env=env)
    assert clear.returncode == 0
    assert not glob.glob(os.path.join(cache, "spidersim_gen_*"))
    assert keep.exists()                      # only spidersim's own files are removed
