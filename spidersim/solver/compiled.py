"""Compile generated diagram modules, with an on-disk cache keyed by their text.

The generated text holds every structural decision (offsets, schedule, integer parameters),
so its hash, together with a hash of spidersim's own sources and the numba version, names the
cached module. numba's own cache (``cache=True``) then lives beside it, so that a second run
of the same diagram structure loads machine code instead of compiling. Parameter values are
not in the text: a new value never recompiles.

The cache folder is ``$SPIDERSIM_CACHE``, else ``~/.cache/spidersim``.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import time
from functools import lru_cache


def cache_dir() -> str:
    d = os.environ.get("SPIDERSIM_CACHE") or os.path.join(
        os.path.expanduser("~"), ".cache", "spidersim")
    os.makedirs(d, exist_ok=True)
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


def load_module(text: str, jit: bool):
    """Import the generated module ``text``; return ``(module, key, seconds)``."""
    key = hashlib.sha256((package_hash() + text).encode()).hexdigest()[:20]
    name = f"spidersim_gen_{key}"
    if name in _LOADED:
        return _LOADED[name], key, 0.0
    t0 = time.perf_counter()
    path = os.path.join(cache_dir(), name + ".py")
    if not os.path.exists(path):
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
        COUNTS["written"] += 1
    COUNTS["imported"] += 1
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    _LOADED[name] = mod
    return mod, key, time.perf_counter() - t0
