"""The compile cache is code the process runs: only a folder the user alone can write is used.

A hostile-input review (session 12) planted files in a shared cache: a ``.pyc`` beside a
verified generated module ran instead of it (Python prefers a ``.pyc`` whose header matches
the source's time and size), numba's ``.nbi`` index files are pickles, and the probe and
temporary files were opened under predictable names through planted symbolic links (a
victim file overwritten). Guarded here: the module is compiled from the verified text, never
from a ``.pyc``; a cache folder (or its ``__pycache__``) that is a link, another user's, or
writable by others is not used (a private fallback is, with a warning); files are created
under random names opened exclusively; ``SPIDERSIM_CACHE`` is expanded and made absolute.
"""
from __future__ import annotations

import importlib.util
import os
import sys
from importlib._bootstrap_external import _code_to_timestamp_pyc

import pytest

from spidersim.solver import compiled

TEXT = '"""A generated module (test)."""\nVALUE = 42\n'


@pytest.fixture
def own(tmp_path, monkeypatch):
    """A private cache folder, a clean module table and fallback."""
    monkeypatch.setenv("SPIDERSIM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(compiled, "_LOADED", {})
    monkeypatch.setattr(compiled, "_FALLBACK", [])
    return tmp_path / "cache"


def _entry_path(cache):
    key = compiled._sha(compiled.package_hash() + TEXT)[:20]
    return cache / f"{compiled.PREFIX}{key}.py", f"{compiled.PREFIX}{key}"


def test_a_planted_pyc_beside_a_verified_module_is_never_run(own, tmp_path, monkeypatch):
    mod, _key, _ = compiled.load_module(TEXT, jit=False)
    assert mod.VALUE == 42
    path, name = _entry_path(own)
    marker = tmp_path / "planted-ran"
    evil = f"open({str(marker)!r}, 'w').write('x')\nVALUE = 666\n"
    st = os.stat(path)
    pyc = importlib.util.cache_from_source(str(path))
    os.makedirs(os.path.dirname(pyc), exist_ok=True)
    with open(pyc, "wb") as fh:
        fh.write(_code_to_timestamp_pyc(compile(evil, str(path), "exec"), st.st_mtime,
                                        st.st_size))
    monkeypatch.setattr(compiled, "_LOADED", {})
    sys.modules.pop(name, None)
    mod, _key, _ = compiled.load_module(TEXT, jit=False)
    assert mod.VALUE == 42 and not marker.exists()


@pytest.mark.parametrize("make", ["world_writable", "group_writable", "symlink",
                                  "pycache_symlink"])
def test_a_folder_others_can_write_is_not_used(own, tmp_path, capsys, make):
    target = tmp_path / "elsewhere"
    target.mkdir()
    if make == "symlink":
        os.symlink(target, own)
    else:
        own.mkdir(mode=0o700)
        if make.endswith("writable") and not make.startswith("pycache"):
            os.chmod(own, 0o777 if make == "world_writable" else 0o770)
        else:
            os.symlink(target, own / "__pycache__")
    used = compiled.cache_dir()
    assert used != str(own)
    err = capsys.readouterr().err
    assert err.count("spidersim: cache:") == 1 and str(own) in err
    assert ("symbolic link" in err) if "symlink" in make else ("written by other users" in err)
    assert compiled._not_private(used) == ""        # the fallback is private
    compiled.load_module(TEXT, jit=False)
    assert not list(target.iterdir()) and not any(
        f.startswith(compiled.PREFIX) for f in os.listdir(own))


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0,
                    reason="giving a folder to another user needs root")
def test_a_folder_of_another_user_is_not_used(own, capsys):
    own.mkdir(mode=0o700)
    os.chown(own, 65534, 65534)
    assert compiled.cache_dir() != str(own)
    assert "belongs to another user" in capsys.readouterr().err


def test_a_new_cache_folder_is_private_and_the_fallback_is_reused(own, tmp_path,
                                                                   monkeypatch):
    assert compiled.cache_dir() == str(own)
    assert (os.stat(own).st_mode & 0o777) == 0o700
    monkeypatch.setattr(compiled.tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    os.chmod(own, 0o777)
    first = compiled._fallback_dir()
    assert first == str(tmp_path / "tmp" / f"spidersim-cache-{os.getuid()}")
    assert compiled._fallback_dir() == first            # reused, not one more per run


def test_files_are_not_written_through_a_link_at_a_predictable_name(own, tmp_path):
    own.mkdir(mode=0o700)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious data")
    path, _name = _entry_path(own)
    for pid_name in (f".probe-{os.getpid()}", f"{path.name}.{os.getpid()}.tmp",
                     f"{path.stem}.sha256.{os.getpid()}.tmp"):
        os.symlink(victim, own / pid_name)
    assert compiled.cache_dir() == str(own)
    compiled.load_module(TEXT, jit=False)
    assert victim.read_text() == "precious data"


@pytest.mark.parametrize("value, expect", [
    ("~/spc", lambda home, cwd: os.path.join(home, "spc")),
    ("rel/cache", lambda home, cwd: os.path.join(cwd, "rel", "cache")),
    ("   ", lambda home, cwd: os.path.join(home, ".cache", "spidersim")),
])
def test_the_configured_folder_is_expanded_and_absolute(monkeypatch, tmp_path, value,
                                                        expect):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SPIDERSIM_CACHE", value)
    assert compiled.configured_dir() == expect(str(tmp_path / "home"), str(tmp_path))


def test_pycache_of_a_private_folder_is_made_private(own):
    """numba makes ``__pycache__`` with the umask's bits (group-writable under umask 002);
    in the user's private cache folder spidersim makes it ``0700`` first, and removes group
    and others' write permission from one that is there, instead of giving up the cache."""
    own.mkdir(mode=0o700)
    (own / "__pycache__").mkdir()
    os.chmod(own / "__pycache__", 0o777)
    assert compiled.cache_dir() == str(own)
    assert (os.stat(own / "__pycache__").st_mode & 0o777) == 0o755


def test_the_fallback_in_use_is_shown_and_cleared(own, tmp_path, monkeypatch, capsys):
    """While the configured folder cannot be used, ``cache info`` names the fallback in use
    with its entries and ``cache clear`` empties it (a broken entry there could not be
    cleared)."""
    from spidersim.cli import main
    monkeypatch.setattr(compiled.tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    own.mkdir(mode=0o700)
    os.chmod(own, 0o777)
    compiled.load_module(TEXT, jit=False)
    fb = compiled.fallback_path()
    assert any(f.startswith(compiled.PREFIX) for f in os.listdir(fb))
    capsys.readouterr()
    assert main(["cache", "info"]) == 0
    out = capsys.readouterr().out
    assert f"in use:  {fb} (1 structure(s)" in out and "can be written by other users" in out
    assert main(["cache", "clear"]) == 0
    assert f"and {fb}" in capsys.readouterr().out
    assert not any(f.startswith(compiled.PREFIX) for f in os.listdir(fb))
