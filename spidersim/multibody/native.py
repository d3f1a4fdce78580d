"""Heavy kernels called through a C symbol: compiled once with spidersim, never linked
into their callers.

numba links the machine-independent code (LLVM IR) of every jitted function a function calls
into that function's module, then optimises and generates machine code for the whole module
again. The arm's dynamics (RNEA, mass matrix by RNEA columns, Cholesky, impact projection)
was re-optimised inside every new diagram that contains an arm: about 8,000 of the 13,500
IR lines of ``spider.yaml``'s ``outputs`` and 3,300 more in its event kernel.

:func:`exported` wraps such a kernel so that compiled callers call it through a C symbol
(``spidersim_mb_<name>``) instead:

* the kernel is compiled once as a C-callable function (:func:`numba.cfunc`, cached on disk
  with spidersim) whose arguments are the data pointers and shapes of its arrays; its
  address is registered under the symbol with LLVM (:func:`llvmlite.binding.add_symbol`)
  when its module is imported, before any code that calls it can be compiled or loaded;
* a compiled caller contains one ``call`` of the external symbol (resolved when its machine
  code is loaded, from numba's cache too), so its module no longer grows with the kernel;
* the call is one direct call, but the caller can no longer be optimised together with the
  kernel. ``mass_matrix``, ``cholesky_solve``, ``impact_projection`` (events, the Chain, the
  force control's task-space inertia) and ``forward_dynamics`` are exported
  (:mod:`.kernels`). ``forward_dynamics`` through its symbol made spider.yaml's right-hand
  side 2-4 % slower in session 6 and was kept linked; in session 7, with one forward
  kinematics per call, the 2 s run measured 0.470-0.473 s through the symbol against
  0.457-0.472 s linked and the 10 s run 2.43-2.59 s against 2.38-2.45 s (2-4 % slower, bit
  for bit the same results) while a new diagram's compile fell from 10.3-10.6 s to
  9.3-9.5 s CPU (the issue's 10 s target), so it is exported.

Caveat: numba's disk cache of a caller does not follow the kernel's module; a caller cached
while a kernel was exported keeps calling its symbol, so a kernel that stops being exported
must keep registering its symbol (or the callers' caches be cleared).

Only float64 C-contiguous arrays of the declared dimensions and integer scalars are passed
this way (the form the blocks pass); any other argument types fall back to calling the
jitted kernel as before (linked in), so nothing breaks for an unusual caller. From Python the
wrapper calls the jitted kernel.
"""
from __future__ import annotations

import llvmlite.binding as llvm
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

#: pointer to float64 (the data of an array) and int64 (a shape, an integer argument)
F64P = types.CPointer(types.float64)
I64 = types.int64


def c_signature(kinds):
    """The C signature of a kernel whose arguments are ``kinds`` (a string: ``1`` a 1-D
    array, ``2`` a 2-D array, ``i`` an integer): every array becomes its data pointer
    followed by its shape (one or two int64), every integer an int64; returns void."""
    args = []
    for k in kinds:
        if k == "i":
            args.append(I64)
        else:
            args += [F64P] + [I64] * int(k)
    return types.void(*args)


def _matches(args, kinds):
    """Whether numba types ``args`` are what the symbol takes (else: the linked fallback)."""
    if len(args) != len(kinds):
        return False
    for ty, k in zip(args, kinds):
        if k == "i":
            if not isinstance(ty, types.Integer):
                return False
        elif not (isinstance(ty, types.Array) and ty.dtype == types.float64
                  and ty.ndim == int(k) and ty.layout == "C"):
            return False
    return True


def _symbol_call(symbol, kinds):
    """An intrinsic ``call(args)`` (``args``: the tuple of the kernel's arguments) that
    calls the external C function ``symbol`` with their data pointers and shapes."""

    @intrinsic
    def call(typingctx, args):
        if not (isinstance(args, types.BaseTuple) and _matches(args.types, kinds)):
            return None

        def codegen(context, builder, signature, llargs):
            tys = signature.args[0].types
            values = cgutils.unpack_tuple(builder, llargs[0], len(tys))
            i64 = ir.IntType(64)
            flat, fl_types = [], []
            for ty, v in zip(tys, values):
                if isinstance(ty, types.Array):
                    arr = context.make_array(ty)(context, builder, v)
                    flat.append(arr.data)
                    fl_types.append(arr.data.type)
                    for s in cgutils.unpack_tuple(builder, arr.shape, ty.ndim):
                        flat.append(s)
                        fl_types.append(i64)
                else:
                    flat.append(context.cast(builder, v, ty, types.int64))
                    fl_types.append(i64)
            fnty = ir.FunctionType(ir.VoidType(), fl_types)
            fn = cgutils.get_or_insert_function(builder.module, fnty, symbol)
            builder.call(fn, flat)
            return context.get_dummy_value()

        return types.none(args), codegen

    return call


def exported(jitted, c_function, kinds):
    """``jitted`` (a numba dispatcher) as a function that compiled callers call through the
    C symbol ``spidersim_mb_<name>`` of ``c_function`` (its cfunc wrapper, signature
    :func:`c_signature` of ``kinds``), registered here; see the module docstring."""
    name = jitted.py_func.__name__
    symbol = f"spidersim_mb_{name}"
    llvm.add_symbol(symbol, c_function.address)
    call = _symbol_call(symbol, kinds)

    def public(*args):
        return jitted(*args)

    public.__name__ = public.__qualname__ = name
    public.__doc__ = jitted.py_func.__doc__
    public.__module__ = jitted.py_func.__module__
    public.symbol = symbol
    public.jitted = jitted

    @overload(public, jit_options={"error_model": "numpy"})
    def _overload(*args):
        if _matches(args, kinds):
            def through_symbol(*args):
                call(args)
            return through_symbol

        def linked(*args):
            jitted(*args)
        return linked

    return public
