"""The system function: one compiled entry point per diagram, called through a pointer.

A generated diagram module exports one C-callable function, ``SYSTEM``, with the fixed
signature :data:`SYSTEM_SIG`::

    value = SYSTEM(task, t, x, sig, p, modes, out, k, f)

``x``, ``sig``, ``p``, ``modes`` and ``out`` are pointers to the first element of C-contiguous
float64 arrays whose lengths the module knows (literals of its layout); ``task`` says what to
do. Because every diagram's function has this one type, everything that calls it (the
compiled integration loop of :mod:`.loop_body`, the stiff methods' Jacobians, the calls from
Python below) is compiled **once** for all diagrams and cached with spidersim itself; a new
diagram compiles its own function only. The function travels as its machine address (an
integer, ``cfunc.address``): compiled callers are typed on an integer, so nothing about a
particular diagram enters their types, and a call costs about 3 ns (one indirect call).

Tasks
-----
====================  ==========================================================  ========
task                  what the system does                                        returns
====================  ==========================================================  ========
``OUTPUTS``           every output into ``sig``, in schedule order                 0
``DERIVATIVES``       outputs, then every state derivative into ``out`` (``n_x``)  0
``GUARDS``            outputs, then every zero-crossing function into ``out``      0
``NEXT_TIME``         nothing (reads ``p``, ``modes``)                             earliest
                                                                                   pending
                                                                                   time event
                                                                                   (``inf``)
``TIME_EVENTS``       apply the time events due by ``t + f`` (``f``: tolerance);   0
                      ``out[k] = 1`` for timed block ``k`` that fired. ``sig``
                      must hold the outputs of ``(t, x)`` (the caller's last
                      evaluation); they are evaluated again only between events
                      that can influence each other
``INITIALIZE``        blocks make their modes consistent with their inputs, then   0
                      every output into ``sig`` (as ``OUTPUTS``)
``APPLY_EVENT``       apply event ``k`` with direction ``f`` on ``x``, ``modes``  0
``GUARDS_AT_SIG``     the zero-crossing functions from the outputs already in      0
                      ``sig`` (the caller's last evaluation was at ``(t, x)``)
``JACOBIAN``          outputs, then ``J = df/dx`` (``n_x * n_x``, C order) from   1 (or 0:
                      the blocks' declared partials into ``out`` (the structural   no
                      nonzeros only; :mod:`spidersim.diagram.jacobian`)            analytic
                                                                                   Jacobian,
                                                                                   nothing
                                                                                   written)
====================  ==========================================================  ========

The functions below are the only way spidersim calls a system function: ``call`` converts
the address to a function pointer and the arrays to data pointers; the others name a task. They are compiled (inlined into their callers)
under numba and plain Python otherwise, where ``fn`` is the module's Python function taking
arrays (interpreted mode, ``JIT = False``).
"""
from __future__ import annotations

import math

import numpy as np

from ._jit import njit, njit_borrowed

OUTPUTS, DERIVATIVES, GUARDS, NEXT_TIME, TIME_EVENTS, INITIALIZE, APPLY_EVENT = range(7)
GUARDS_AT_SIG = 7
JACOBIAN = 8
TASKS = ("OUTPUTS", "DERIVATIVES", "GUARDS", "NEXT_TIME", "TIME_EVENTS", "INITIALIZE",
         "APPLY_EVENT", "GUARDS_AT_SIG", "JACOBIAN")

try:
    from numba import types
    from numba.extending import intrinsic, overload

    _P = types.CPointer(types.float64)
    #: ``float64(task, t, x, sig, p, modes, out, k, f)`` with pointer arguments
    SYSTEM_SIG = types.float64(types.int64, types.float64, _P, _P, _P, _P, _P, types.int64,
                               types.float64)
except ImportError:  # pragma: no cover - numba is a dependency
    intrinsic = overload = None
    SYSTEM_SIG = None


def call(fn, task, t, x, sig, p, modes, out, k, f):
    """``fn(task, t, x, sig, p, modes, out, k, f)``: in Python, with the arrays themselves."""
    return fn(task, t, x, sig, p, modes, out, k, f)


if intrinsic is not None:
    from llvmlite import ir

    @intrinsic
    def _call_address(typingctx, address, task, t, x, sig, p, modes, out, k, f):
        """Call the C function at ``address`` (an integer: ``cfunc.address``) with the data
        pointers of the five arrays (no reference is taken: the arrays outlive the call)."""
        arrays = (x, sig, p, modes, out)
        # ``out`` may be a C-contiguous matrix (the Jacobian): its data pointer is passed
        if not (isinstance(address, types.Integer) and all(
                isinstance(a, types.Array) and a.dtype == types.float64 and a.ndim == 1
                for a in arrays[:4]) and isinstance(out, types.Array)
                and out.dtype == types.float64 and (out.ndim == 1 or out.layout == "C")):
            return None

        def codegen(context, builder, signature, args):
            dbl, i64 = ir.DoubleType(), ir.IntType(64)
            ptr = ir.PointerType(dbl)
            fnty = ir.FunctionType(dbl, [i64, dbl, ptr, ptr, ptr, ptr, ptr, i64, dbl])
            target = builder.inttoptr(args[0], fnty.as_pointer())
            data = [context.make_array(ty)(context, builder, v).data
                    for ty, v in zip(signature.args[3:8], args[3:8])]
            task_, t_ = args[1], args[2]
            k_, f_ = args[8], args[9]
            task_ = context.cast(builder, task_, signature.args[1], types.int64)
            t_ = context.cast(builder, t_, signature.args[2], types.float64)
            k_ = context.cast(builder, k_, signature.args[8], types.int64)
            f_ = context.cast(builder, f_, signature.args[9], types.float64)
            return builder.call(target, [task_, t_] + data + [k_, f_])

        return types.float64(address, task, t, x, sig, p, modes, out, k, f), codegen

    @overload(call, inline="always")
    def _call_jit(fn, task, t, x, sig, p, modes, out, k, f):
        def impl(fn, task, t, x, sig, p, modes, out, k, f):
            return _call_address(fn, task, t, x, sig, p, modes, out, k, f)
        return impl


@njit_borrowed
def outputs(fn, t, x, sig, p, modes):
    """Every output into ``sig``."""
    call(fn, OUTPUTS, t, x, sig, p, modes, sig, 0, 0.0)


@njit_borrowed
def derivatives(fn, t, x, sig, p, modes, xdot):
    """Outputs, then ``xdot = f(t, x)``."""
    call(fn, DERIVATIVES, t, x, sig, p, modes, xdot, 0, 0.0)


@njit
def rhs(fn, t, x, sig, p, modes):
    """``f(t, x)`` as a new array (SciPy's interface)."""
    xdot = np.zeros(x.size)
    call(fn, DERIVATIVES, t, x, sig, p, modes, xdot, 0, 0.0)
    return xdot


@njit_borrowed
def guards(fn, t, x, sig, p, modes, g):
    """Outputs, then the zero-crossing functions into ``g``."""
    call(fn, GUARDS, t, x, sig, p, modes, g, 0, 0.0)


@njit_borrowed
def guards_at_sig(fn, t, x, sig, p, modes, g):
    """The zero-crossing functions into ``g`` from the outputs in ``sig``, which must be
    those of ``(t, x)`` (the last ``derivatives`` call was there): one evaluation saved
    per step."""
    call(fn, GUARDS_AT_SIG, t, x, sig, p, modes, g, 0, 0.0)


@njit_borrowed
def next_time(fn, t, p, modes):
    """The earliest pending time event (``inf``: none)."""
    return call(fn, NEXT_TIME, t, modes, modes, p, modes, modes, 0, 0.0)


@njit_borrowed
def time_events(fn, t, x, sig, p, modes, tol, fired):
    """Apply the time events due by ``t + tol``; ``fired[k] = 1`` for each timed block ``k``
    that fired (``fired`` float64, one entry per timed block, at least one). ``sig`` must
    hold the outputs of ``(t, x)``."""
    call(fn, TIME_EVENTS, t, x, sig, p, modes, fired, 0, tol)


@njit_borrowed
def initialize(fn, t, x, sig, p, modes):
    """Blocks make their modes consistent with their inputs (start, after events)."""
    call(fn, INITIALIZE, t, x, sig, p, modes, sig, 0, 0.0)


@njit_borrowed
def apply_event(fn, t, x, sig, p, modes, k, direction):
    """Apply event ``k`` (a guard index; ``-1``: none, for a warm-up) with ``direction``."""
    call(fn, APPLY_EVENT, t, x, sig, p, modes, sig, k, direction)


@njit_borrowed
def jacobian(fn, t, x, sig, p, modes, J):
    """Outputs, then the analytic ``J = df/dx`` (``J``: ``(n_x, n_x)``, C order; only the
    structural nonzeros are written); returns False, with nothing written, when the system
    has no analytic Jacobian (the caller uses finite differences)."""
    return call(fn, JACOBIAN, t, x, sig, p, modes, J, 0, 0.0) != 0.0


@njit_borrowed
def record(fn, t, x, sig, p, modes, s_idx, x_idx, buf, row):
    """Outputs at ``(t, x)``, then the logged signals ``sig[s_idx]`` and states
    ``x[x_idx]`` into ``buf[row]``; False when ``x`` or a logged value is not finite."""
    call(fn, OUTPUTS, t, x, sig, p, modes, sig, 0, 0.0)
    return copy_row(x, sig, s_idx, x_idx, buf, row)


@njit_borrowed
def record_guards(fn, t, x, sig, p, modes, s_idx, x_idx, buf, row, g):
    """:func:`record` and the guards into ``g`` from one evaluation of the outputs."""
    call(fn, GUARDS, t, x, sig, p, modes, g, 0, 0.0)
    return copy_row(x, sig, s_idx, x_idx, buf, row)


@njit_borrowed
def copy_row(x, sig, s_idx, x_idx, buf, row):
    """The logged signals ``sig[s_idx]`` and states ``x[x_idx]`` into ``buf[row]`` (``sig``
    must hold the outputs of ``(t, x)``); False when ``x`` or a logged value is not
    finite."""
    ok = True
    for i in range(x.size):
        if not math.isfinite(x[i]):
            ok = False
    k = 0
    for i in s_idx:
        v = sig[i]
        buf[row, k] = v
        if not math.isfinite(v):
            ok = False
        k += 1
    for i in x_idx:
        buf[row, k] = x[i]
        k += 1
    return ok


_ENTRY: dict = {}


def entry_point(dispatcher, args):
    """The machine code of ``dispatcher`` for the types of ``args`` (looked up once per
    process and dispatcher: the callers always pass the same types), or None when it is not
    compiled for them yet."""
    e = _ENTRY.get(dispatcher)
    if e is None:
        import numba
        over = dispatcher.overloads.get(tuple(numba.typeof(a) for a in args))
        if over is None:
            return None
        e = _ENTRY[dispatcher] = over.entry_point
    return e
