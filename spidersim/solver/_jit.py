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

    def for_method(stub):
        """Register the decorated typing function as the compiled form of ``stub(meth,
        ...)``, a function of the integration method ``meth`` (:mod:`.loop_state`): it
        returns the implementation for ``meth``'s type, a Python function with ``stub``'s
        arguments. When ``meth`` is a compile-time constant (a literal, as the loop's entry
        per method passes it), only that method's implementation is typed and compiled, so a
        DP54 run never compiles the stiff solvers; otherwise ``stub`` itself (it branches at
        run time). Inlined into the caller (numba IR), as the parts called every step."""
        from numba.extending import overload

        def register(typer):
            overload(stub, prefer_literal=True, inline="always",
                     jit_options=dict(nogil=True, error_model="numpy", _nrt=False))(typer)
            return typer
        return register

    def literal_method(meth, impls, generic):
        """``impls[value]`` when the type ``meth`` is an integer literal, else ``generic``
        (for :func:`for_method`'s typing functions)."""
        from numba.core import types
        if isinstance(meth, types.IntegerLiteral):
            return impls[meth.literal_value]
        return generic
except ImportError:  # pragma: no cover - numba is a dependency
    def for_method(stub):
        return lambda typer: typer

    def literal_method(meth, impls, generic):
        return generic

    def njit(f):
        return f

    def njit_borrowed(f=None, inline="never"):
        return f if f is not None else (lambda g: g)
