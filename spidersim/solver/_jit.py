"""The one numba decorator of the fixed solver modules (cached machine code, numpy error
model: a division by zero gives inf/nan, reported by name, instead of an exception)."""
from __future__ import annotations

try:
    from numba import njit as _njit

    def njit(f):
        return _njit(cache=True, nogil=True, error_model="numpy")(f)
except ImportError:  # pragma: no cover - numba is a dependency
    def njit(f):
        return f
