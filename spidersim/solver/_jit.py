"""The numba decorators of the fixed solver modules (cached machine code, numpy error
model: a division by zero gives inf/nan, reported by name, instead of an exception)."""
from __future__ import annotations

try:
    from numba import njit as _njit

    def njit(f):
        return _njit(cache=True, nogil=True, error_model="numpy")(f)

    def njit_borrowed(f=None, inline="never"):
        """:func:`njit` without numba's reference counting (``_nrt=False``), for code that
        only reads and writes arrays it is given (views included) and allocates nothing:
        every array view and every array passed to a function otherwise costs an atomic
        increment and decrement of the array's reference count. ``inline="always"``: numba
        inlines the function into its callers (for small functions called every step, whose
        call would pass every array as its seven or nine fields)."""
        if f is None:
            return lambda g: njit_borrowed(g, inline)
        return _njit(cache=True, nogil=True, error_model="numpy", _nrt=False,
                     inline=inline)(f)
except ImportError:  # pragma: no cover - numba is a dependency
    def njit(f):
        return f

    def njit_borrowed(f=None, inline="never"):
        return f if f is not None else (lambda g: g)
