"""Compile generated diagram modules, with an on-disk cache keyed by their text.

The generated text holds every structural decision (offsets, schedule, integer parameters),
so its hash, together with a hash of spidersim's own sources and the numba version, names the
cached module. numba's own cache (``cache=True``) then lives beside it, so that a second run
of the same diagram structure loads machine code instead of compiling. Parameter values are
not in the text: a new value never recompiles.

The cache folder is ``$SPIDERSIM_CACHE`` (``~`` expanded, made absolute), else
``~/.cache/spidersim``. What is loaded from it becomes code in the process (the generated
module; numba's index files are pickles), so the folder must be one only the user can
write: a real folder (not a symbolic link) owned by the user and not writable by group or
others, and so must numba's ``__pycache__`` in it; a folder spidersim creates is made
``0700``. A folder that is not writable, or not private (a shared cache another user could
plant files in), is not used: a private folder of the user's in the temporary directory
(``spidersim-cache-<uid>``, checked the same way; else a fresh one removed at exit) is,
with a one-line warning. Every entry is verified before it is imported (its text, the hash
written beside it and its key must agree): a truncated, emptied, appended or swapped entry
is discarded and compiled again; the module is compiled from the verified text itself,
never from a ``.pyc`` beside it. Files are written under random names opened exclusively,
then renamed. ``spidersim cache info`` and ``spidersim cache clear`` show and empty it.
"""
from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import os
import re
import stat
import sys
import tempfile
import time
from functools import lru_cache


_FALLBACK: list = []     # the private temporary folder used when the cache is unusable


def _warn(msg):
    print(f"spidersim: cache: {msg}", file=sys.stderr)


def _not_private(d) -> str:
    """Why folder ``d`` is not the user's alone ('' when it is): a symbolic link, not a
    folder, another owner, or writable by group or others."""
    try:
        st = os.lstat(d)
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if stat.S_ISLNK(st.st_mode):
        return "is a symbolic link"
    if not stat.S_ISDIR(st.st_mode):
        return "is not a folder"
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return "belongs to another user"
    if st.st_mode & 0o022:
        return "can be written by other users"
    return ""


def _problem(d) -> str:
    """Why ``d`` cannot be the cache ('' when it can): it is made (``0700``) if missing,
    must be private (:func:`_not_private`, and its ``__pycache__`` if there) and writable
    (a probe file under a random name, opened exclusively)."""
    pyc = os.path.join(d, "__pycache__")
    try:
        os.makedirs(d, mode=0o700, exist_ok=True)
        if d == _default_dir():
            _tighten(d)          # made before spidersim made it private (umask 002)
        if not _not_private(d):
            if not os.path.lexists(pyc):
                os.mkdir(pyc, 0o700)        # numba would make it with the umask's bits
            _tighten(pyc)
    except OSError:
        return "is not a writable folder"
    why = _not_private(d)
    if not why and _not_private(pyc):
        why = f"has a __pycache__ that {_not_private(pyc)}"
    if why:
        return why
    try:
        fd, probe = tempfile.mkstemp(prefix=".probe-", dir=d)
        os.close(fd)
        os.remove(probe)
    except OSError:
        return "is not a writable folder"
    return ""


def _tighten(d):
    """Remove group and others' write permission from the user's own real folder ``d``
    (spidersim's own folders: the default cache and ``__pycache__`` in a private one)."""
    st = os.lstat(d)
    if stat.S_ISDIR(st.st_mode) and (not hasattr(os, "getuid") or st.st_uid == os.getuid()) \
            and st.st_mode & 0o022:
        os.chmod(d, stat.S_IMODE(st.st_mode) & ~0o022)


def _default_dir() -> str:
    return os.path.join(os.path.expanduser("~"), ".cache", "spidersim")


def configured_dir() -> str:
    """The cache folder asked for: ``$SPIDERSIM_CACHE`` (``~`` expanded, absolute; blank
    means unset), else ``~/.cache/spidersim``."""
    d = os.environ.get("SPIDERSIM_CACHE", "").strip()
    return os.path.abspath(os.path.expanduser(d)) if d else _default_dir()


def cache_dir() -> str:
    """The cache folder in use: the configured one when it can be (:func:`_problem`), else
    the user's private fallback folder (with a one-line warning, once per process)."""
    d = configured_dir()
    why = _problem(d)
    if not why:
        return d
    if not _FALLBACK:
        _FALLBACK.append(_fallback_dir())
        _warn(f"{d} {why}; compiling into {_FALLBACK[0]} instead (set SPIDERSIM_CACHE to a "
              f"folder of your own that only you can write to keep compiled code there)")
    return _FALLBACK[0]


def fallback_path() -> str:
    """``<tmp>/spidersim-cache-<uid>``: the user's fallback cache folder."""
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    return os.path.join(tempfile.gettempdir(), f"spidersim-cache-{uid}")


def _fallback_dir() -> str:
    """``<tmp>/spidersim-cache-<uid>`` when it is (or can be made) the user's private
    folder, kept for later runs; else a fresh private folder removed at exit."""
    d = fallback_path()
    if not _problem(d):
        return d
    import atexit
    import shutil
    d = tempfile.mkdtemp(prefix="spidersim-cache-")
    atexit.register(shutil.rmtree, d, True)
    return d


@lru_cache(maxsize=1)
def package_hash() -> str:
    """Hash of spidersim's source files: editing a block invalidates compiled diagrams."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    h = hashlib.sha256()
    for dirpath, dirnames, files in sorted(os.walk(root)):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
        for f in sorted(files):
            if f.endswith(".py"):
                with open(os.path.join(dirpath, f), "rb") as fh:
                    h.update(f.encode() + fh.read())
    try:
        import numba
        h.update(numba.__version__.encode())
    except ImportError:  # interpreted mode only
        pass
    return h.hexdigest()[:16]


_LOADED: dict = {}
#: per process: generated modules written to the cache (new structures, numba compiles
#: them) and imported from it (numba loads their machine code)
COUNTS = {"written": 0, "imported": 0}


PREFIX = "spidersim_gen_"
#: the files of a cache entry: the module and its hash (``spidersim_gen_<20 hex>.py``,
#: ``.sha256``) in the folder, numba's index and machine code in ``__pycache__``
#: (``spidersim_gen_<key>.<function>-<line>.py311.nbi``, ``...nbc``, Python's ``.pyc``)
_ENTRY_FILE = re.compile(r"^spidersim_gen_[0-9a-f]{20}(\.py|\.sha256|[.-].*\.(nbi|nbc|pyc))$")


def refresh_kernel_caches(root=None) -> bool:
    """Drop numba's machine code of spidersim's own kernels when any source file changed;
    return True when it did.

    numba keys a cached function by its own file's time stamp and size only: after an edit
    of ``multibody/kernels.py``, the Arm block's kernels (in ``blocks/arm.py``), which have
    the forward dynamics compiled into them, would still load the old machine code. A stamp
    holding :func:`package_hash` beside the caches detects any change of any source file (or
    of numba's version); then every ``*.nbi``/``*.nbc`` under the package is removed and
    numba compiles again on first use. A package folder that is not writable is left alone
    (numba cannot cache there either: it then caches in the user's cache folder, keyed by
    file time stamps: a known limit, see the README). ``root``: the package folder (tests).
    """
    root = root or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    stamp = os.path.join(root, "__pycache__", "numba-kernels.stamp")
    h = package_hash()
    try:
        with open(stamp) as fh:
            if fh.read() == h:
                return False
    except OSError:
        pass
    if not os.access(root, os.W_OK):
        return False
    for dirpath, _dirs, files in os.walk(root):
        if os.path.basename(dirpath) == "__pycache__":
            for f in files:
                if f.endswith((".nbi", ".nbc")):
                    _remove(os.path.join(dirpath, f))
    try:
        os.makedirs(os.path.dirname(stamp), exist_ok=True)
        _write_atomic(stamp, h)
    except OSError:
        pass
    return True


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _write_atomic(path, text):
    """``text`` into ``path``: written to a new file of a random name opened exclusively
    (never through a link planted under a predictable name), then renamed."""
    fd, tmp = tempfile.mkstemp(prefix=os.path.basename(path) + ".", suffix=".tmp",
                               dir=os.path.dirname(path))
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        _remove(tmp)
        raise


def _numba_files(folder, name):
    pyc = os.path.join(folder, "__pycache__")
    if not os.path.isdir(pyc):
        return []
    return [os.path.join(pyc, f) for f in os.listdir(pyc) if f.startswith(name + ".")
            or f.startswith(name + "-")]


def _verified(path, text, key) -> bool:
    """The cached module at ``path`` is exactly ``text``, its recorded hash matches and its
    name is the key of its content: anything else (truncated, emptied, appended, swapped
    for another diagram's, hash missing) is not trusted."""
    try:
        with open(path, encoding="utf-8") as fh:
            content = fh.read()
        with open(path[:-3] + ".sha256", encoding="ascii") as fh:
            recorded = fh.read().strip()
    except (OSError, UnicodeDecodeError):
        return False
    return (content == text and recorded == _sha(content)
            and _sha(package_hash() + content)[:20] == key)


def load_module(text: str, jit: bool, check=None):
    """Import the generated module ``text``; return ``(module, key, seconds)``.

    The cache entry is verified before it is imported (see :func:`_verified`); an entry
    that fails is discarded with a one-line warning and written anew, so numba compiles it
    again. Module and hash are written to temporary names and renamed (atomic).

    ``check(module)``, when given, is run right after the import (the warm-up: numba loads
    or compiles the machine code when a function is first called). If the import or the
    check fails on a verified module, numba's cache files of the entry are the suspects
    (truncated, corrupt index): they are removed and the module imported and checked once
    more, with a one-line warning. A :class:`~spidersim.errors.SpidersimError` from
    ``check`` is the user's and is raised as it is.
    """
    from ..errors import SpidersimError
    key = _sha(package_hash() + text)[:20]
    name = f"{PREFIX}{key}"
    if name in _LOADED:
        return _LOADED[name], key, 0.0
    t0 = time.perf_counter()
    folder = cache_dir()
    path = os.path.join(folder, name + ".py")
    if os.path.exists(path) and not _verified(path, text, key):
        _warn(f"entry {key} does not match its hash (truncated, edited or replaced); "
              f"discarded and compiled again")
        for f in [path, path[:-3] + ".sha256"] + _numba_files(folder, name):
            _remove(f)
    if not os.path.exists(path):
        _write_atomic(path[:-3] + ".sha256", _sha(text) + "\n")
        _write_atomic(path, text)
        COUNTS["written"] += 1
    COUNTS["imported"] += 1

    def attempt():
        mod = _import(name, path, text)
        if check is not None:
            check(mod)
        return mod
    try:
        mod = attempt()
    except SpidersimError:
        raise
    except Exception as exc:  # a corrupt numba cache beside a verified module: once more
        had = _numba_files(folder, name)
        for f in had:
            _remove(f)
        if not had:              # nothing of numba's to blame: a genuine error
            raise
        _warn(f"entry {key}: its compiled machine code could not be loaded "
              f"({type(exc).__name__}); discarded, compiling again")
        try:
            mod = attempt()
        except SpidersimError:
            raise
        except Exception as exc2:
            raise SpidersimError(f"the compiled-code cache entry {key} in {folder} cannot be "
                                 f"loaded ({type(exc2).__name__}: {exc2}); run "
                                 f"'spidersim cache clear' and try again") from None
    _LOADED[name] = mod
    return mod, key, time.perf_counter() - t0


def _remove(f):
    try:
        os.remove(f)
    except OSError:
        pass


def is_cached(text: str, loop=False) -> bool:
    """Whether the module ``text`` is already compiled in the cache (verified), i.e. the
    next :func:`load_module` loads machine code instead of compiling; with ``loop`` (True:
    DP54, or a method's name), the compiled integration loop's entry of that method too
    (compiled once for every diagram, cached by numba with spidersim's own kernels)."""
    key = _sha(package_hash() + text)[:20]
    name = f"{PREFIX}{key}"
    path = os.path.join(cache_dir(), name + ".py")
    if loop and not loop_cached(loop if isinstance(loop, str) else "DP54"):
        return False
    if name in _LOADED:
        return True
    files = _numba_files(os.path.dirname(path), name)
    return os.path.exists(path) and _verified(path, text, key) and bool(files)


def loop_cached(method="DP54") -> bool:
    """Whether the integration loop's entry of ``method`` has machine code loaded or in
    numba's cache."""
    from .system import loop_entry
    entry = loop_entry(method)
    if entry.overloads:
        return True
    try:
        cache_path = entry._cache._cache_path
        prefix = f"loop_body.{entry.py_func.__name__}-"
        return any(f.startswith(prefix) and f.endswith(".nbi")
                   for f in os.listdir(cache_path))
    except (AttributeError, OSError):
        return False


class _VerifiedSource(importlib.machinery.SourceFileLoader):
    """Compiles the module from the text that was verified, never from a ``.pyc`` found
    beside the file (one planted there would run instead of the checked source) and without
    reading the file again."""

    def __init__(self, name, path, text):
        super().__init__(name, path)
        self._text = text

    def get_code(self, fullname):
        return self.source_to_code(self._text.encode("utf-8"), self.path)


def _import(name, path, text):
    spec = importlib.util.spec_from_file_location(name, path,
                                                  loader=_VerifiedSource(name, path, text))
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    try:
        spec.loader.exec_module(mod)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return mod


def info() -> dict:
    """Folder, number of compiled diagram structures and bytes used by the cache."""
    folder = configured_dir()
    entries, size = _count(folder)
    out = {"folder": folder, "entries": entries, "bytes": size,
           "usable": (_problem(folder) or True) if os.path.exists(folder) else None}
    if isinstance(out["usable"], str):            # the fallback is in use instead
        fb = fallback_path()
        out["fallback"] = fb
        out["fallback_entries"], out["fallback_bytes"] = _count(fb)
    return out


def _count(folder):
    """Compiled structures and bytes of spidersim's own cache files in ``folder``: the
    files of cache entries (:data:`_ENTRY_FILE`, as :func:`clear` removes them) in the
    folder and its ``__pycache__``, nothing deeper (with ``SPIDERSIM_CACHE=/`` the whole
    file system was walked and every ``spidersim_gen_*`` anywhere counted). Links are not
    followed."""
    entries, size = 0, 0
    for d in (folder, os.path.join(folder, "__pycache__")):
        try:
            listing = os.scandir(d)
        except OSError:                    # absent, not a folder, not readable
            continue
        with listing:
            for f in listing:
                if not (_ENTRY_FILE.match(f.name) and f.is_file(follow_symlinks=False)):
                    continue
                try:
                    size += f.stat(follow_symlinks=False).st_size
                except OSError:            # removed meanwhile
                    continue
                entries += d == folder and f.name.endswith(".py")
    return entries, size


def clear() -> int:
    """Remove every cache file spidersim wrote (:data:`_ENTRY_FILE`: a file merely named
    ``spidersim_gen_...`` by someone else stays) and nothing else; return how many were
    removed. The user's fallback folder (used while the configured one cannot be) is
    emptied too."""
    folders = [configured_dir()]
    if os.path.isdir(fallback_path()) and not _not_private(fallback_path()):
        folders.append(fallback_path())
    n = 0
    for d in [f for folder in folders for f in (folder, os.path.join(folder, "__pycache__"))]:
        if not os.path.isdir(d):
            continue
        for f in os.listdir(d):
            if _ENTRY_FILE.match(f) and os.path.isfile(os.path.join(d, f)):
                try:
                    os.remove(os.path.join(d, f))
                    n += 1
                except OSError:
                    pass
    for name in [k for k in _LOADED]:
        del _LOADED[name]
    return n
